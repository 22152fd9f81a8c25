"""Gross errors in the measurements: a robust scale of the residuals and the rule that flags samples.

A tracker that loses its line of sight, a reflector knocked or a pose logged against the wrong
reading gives a few samples millimetres off while the rest are right to the noise. Least squares
gives each of them the weight of hundreds of good samples: they bend the calibration, inflate the
residual scale (hiding a real effect) or leave a pattern a catalog effect takes (creating one). This
module owns the statistics of the screen (domain-free, on whitened residuals ``w`` of shape
``(N, m)``); the kinematic problem's robust refit and the screen's passes are
:mod:`plugins.model_gap.robust_fit`.

**Robust scale** (:func:`robust_scale`). For a correct model the whitened per-sample sum of squares
``d_i = |w_i|^2`` is ``s^2 chi2(m)`` (``s`` = 1 when the stated noise is right), so
``s_0 = sqrt(median(d) / median(chi2(m)))`` (the median-based start, 50 % breakdown), corrected by
``sqrt(M / (M - p))`` for the ``p`` parameters the fit used. It is then refined on the samples inside
the cut below (a truncated mean of ``d``, divided by the truncated chi-square's mean: ~2x the
efficiency of the median), iterated to a fixed point.

**Flag rule** (:func:`flag_outliers`): sample ``i`` is a gross error when ``d_i / s^2`` exceeds the
``1 - alpha / N`` quantile of ``chi2(m)`` (Bonferroni over the samples): on Gaussian noise the
probability that a campaign loses *any* good sample is at most ``alpha`` (default 1 %), i.e. a
per-sample rate of ``alpha / N``. The scale is estimated from the same residuals, so the realised
rate is somewhat higher on small campaigns (the benchmark measures it).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from plugins.model_gap.core.interfaces import F64

DEFAULT_OUTLIER_ALPHA = 0.01  # probability that a Gaussian-noise campaign loses any good sample


@dataclass
class OutlierScreen:
    """The samples left out as gross errors, and the figures that decided it."""

    alpha: float  # family-wise: P(any good sample flagged) on Gaussian noise
    cut: float  # whitened |w_i|^2 / s^2 above which a sample is flagged (chi2(m) quantile 1 - alpha / N)
    scale: float  # robust residual scale (x the stated / provisional noise sigma)
    n_samples: int  # samples screened (the whole campaign)
    ids: list[int] = field(default_factory=list)  # flagged rows of the data (0-based), ascending
    residual: list[float] = field(default_factory=list)  # their 3-D residual norms (SI), same order
    ratio: list[float] = field(default_factory=list)  # their norms over the robust 3-D scale
    passes: int = 1  # screens run (baseline, then again with the final model until the set is stable)
    stable: bool = True  # the last pass flagged the samples the model was fitted without
    notes: list[str] = field(default_factory=list)

    @property
    def n_flagged(self) -> int:
        return len(self.ids)

    def describe(self, unit: str = "mm", scale: float = 1e3, top: int = 8) -> str:
        """``3 of 150 samples left out as gross errors (rows 4, 17, 90: 2.1, 4.0, 1.3 mm, > 4.6x ...)``."""
        if not self.ids:
            return f"no sample left out as a gross error (0 of {self.n_samples} beyond the cut)"
        rows = ", ".join(str(i) for i in self.ids[:top]) + (" ..." if len(self.ids) > top else "")
        sizes = ", ".join(f"{r * scale:.3g}" for r in self.residual[:top])
        return (
            f"{len(self.ids)} of {self.n_samples} samples left out as gross errors (rows {rows}: residual {sizes} "
            f"{unit}, beyond {np.sqrt(self.cut):.2f}x the robust residual scale; chance would flag a good sample in "
            f"{self.alpha:.0%} of campaigns)"
        )


def _d(w: F64) -> F64:
    w = np.asarray(w, dtype=float)
    if w.ndim != 2 or w.shape[0] == 0 or not np.all(np.isfinite(w)):
        raise ValueError("residuals must be a finite (N, m) array with N >= 1")
    return np.sum(w**2, axis=1)


def cut_for(n_samples: int, m: int, alpha: float) -> float:
    """The chi2(m) quantile ``1 - alpha / N``: the flag threshold on ``|w_i|^2 / s^2``."""
    if not (0.0 < alpha < 1.0) or n_samples < 1 or m < 1:
        raise ValueError(f"need 0 < alpha < 1, N >= 1, m >= 1 (got {alpha}, {n_samples}, {m})")
    return float(stats.chi2.isf(alpha / n_samples, m))


def robust_scale(w: F64, n_params: int = 0, *, alpha: float = DEFAULT_OUTLIER_ALPHA, iterations: int = 10) -> float:
    """The robust residual scale ``s`` of the module docstring (whitened units: 1 = the stated noise)."""
    d = _d(w)
    N, m = np.asarray(w).shape
    M = N * m
    dof_factor = M / max(M - n_params, 1)
    s2 = float(np.median(d)) / stats.chi2.ppf(0.5, m) * dof_factor
    if s2 <= 0:
        return 0.0
    cut = cut_for(N, m, alpha)
    # the mean of chi2(m) truncated at `cut`, over m: the truncated mean's consistency factor
    trunc = float(stats.chi2.cdf(cut, m + 2) / stats.chi2.cdf(cut, m))
    for _ in range(iterations):
        inside = d <= cut * s2
        if inside.sum() < max(3, N // 2):
            break
        new = float(np.mean(d[inside])) / (m * trunc) * dof_factor
        if abs(new - s2) <= 1e-9 * s2:
            s2 = new
            break
        s2 = new
    return float(np.sqrt(s2))


def flag_outliers(w: F64, scale: float, alpha: float = DEFAULT_OUTLIER_ALPHA) -> np.ndarray:
    """Boolean ``(N,)``: the samples beyond the cut (module docstring) at the robust ``scale``."""
    d = _d(w)
    N, m = np.asarray(w).shape
    if not (np.isfinite(scale) and scale > 0):
        return np.zeros(N, dtype=bool)
    return d > cut_for(N, m, alpha) * scale**2


def screen(
    w: F64, sigma_phys: F64, n_params: int, alpha: float = DEFAULT_OUTLIER_ALPHA, *, scale: float | None = None
) -> tuple[np.ndarray, OutlierScreen]:
    """Flag the gross errors of whitened residuals ``w`` (``sigma_phys``: each sample's sigma, SI);
    ``scale`` given: use it (the scale of the samples a model was fitted on), else :func:`robust_scale`."""
    s = robust_scale(w, n_params, alpha=alpha) if scale is None else float(scale)
    mask = flag_outliers(w, s, alpha)
    N, m = w.shape
    norms = np.linalg.norm(w, axis=1)
    idx = np.flatnonzero(mask)
    sc = OutlierScreen(
        alpha,
        cut_for(N, m, alpha),
        s,
        N,
        idx.tolist(),
        (norms[idx] * np.asarray(sigma_phys, dtype=float)[idx]).tolist(),
        (norms[idx] / (s * np.sqrt(m)) if s > 0 else norms[idx]).tolist(),
    )
    return mask, sc
