"""Where the gap concentrates: residuals binned along each feature (joint angle, torque, time ...).

For a feature the samples are split into bins (quantiles for continuous features, the values for
categorical ones such as an approach direction). Two statistics compare the bins with each other
(not with the noise specification: a gap inflates the residuals everywhere, and the question here is
*where* it is larger). With ``s2`` the mean squared whitened residual component over all samples:

* **mean shift** ``S = sum_b n_b |mean_b(w) - mean(w)|^2 / s2 ~ chi2(m (B - 1))``: the residual has a
  systematic part that changes along the feature (backlash flips with the direction, compliance
  grows with the torque, drift with time);
* **spread** ``T = sum_b n_b (mean_b(|w|^2) - mean(|w|^2))^2 / var(|w|^2) ~ chi2(B - 1)``
  (approximately): the residual's size changes along the feature without a consistent direction
  (latency grows with speed).

Features are ranked by the stronger statistic's normal score; each bin reports its sample count,
range and 3-D RMS and mean residual in physical units, so a reader sees *where* the model disagrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from plugins.model_gap.core.interfaces import Feature, Linearisation


@dataclass
class BinSummary:
    label: str
    n: int
    rms: float  # 3-D RMS (SI)
    mean: list[float]  # mean residual per component (SI)


@dataclass
class FeatureGap:
    name: str
    label: str
    unit: str
    mean_chi2: float
    mean_p: float
    spread_chi2: float
    spread_p: float
    log10_p: float = 0.0  # of the smaller p-value
    z: float = 0.0  # Wilson-Hilferty normal score of the stronger statistic (ranks even when p underflows)
    bins: list[BinSummary] = field(default_factory=list)

    @property
    def p(self) -> float:
        return min(self.mean_p, self.spread_p)


def _wilson_hilferty(x: float, k: int) -> float:
    """Normal score of a chi-square(k) value (no underflow for huge statistics)."""
    return float(((x / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9 * k))) / np.sqrt(2.0 / (9 * k)))


def _bins(f: Feature, n_bins: int) -> list[tuple[str, np.ndarray]]:
    v = np.asarray(f.values, dtype=float)
    scale = float(np.max(np.abs(v))) if v.size else 0.0
    if scale > 0 and not f.categorical:  # equal up to rounding (rows of one pose) must share a bin
        v = np.round(v / scale, 9) * scale
    if f.categorical:
        return [(f"{val:g}", v == val) for val in np.unique(v)]
    edges = np.unique(np.quantile(v, np.linspace(0, 1, n_bins + 1)))
    if edges.size < 2:
        return [(f"{edges[0]:.4g}", np.ones(v.size, bool))]
    idx = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, edges.size - 2)
    return [(f"{edges[b]:.4g}..{edges[b + 1]:.4g}", idx == b) for b in range(edges.size - 1)]


def localise(lin: Linearisation, features: list[Feature], n_bins: int = 4, min_bin: int = 5) -> list[FeatureGap]:
    """Bin the residuals along every feature; most concentrated first (see the module docstring)."""
    w = lin.residual
    phys = lin.physical_residual()
    m = w.shape[1]
    w_mean = w.mean(axis=0)
    s2 = max(float(np.mean((w - w_mean) ** 2)), 1e-300)
    sq = np.sum(w**2, axis=1)
    sq_var = max(float(np.var(sq, ddof=1)) if sq.size > 1 else 0.0, 1e-300)
    out = []
    for f in features:
        if f.values.shape != (w.shape[0],) or not np.all(np.isfinite(f.values)):
            continue
        groups = [(lab, mask) for lab, mask in _bins(f, n_bins) if mask.sum() >= min_bin]
        if len(groups) < 2:
            continue
        S = T = 0.0
        bins = []
        for lab, mask in groups:
            n = int(mask.sum())
            d = w[mask].mean(axis=0) - w_mean
            S += n * float(d @ d) / s2
            T += n * (float(sq[mask].mean()) - float(sq.mean())) ** 2 / sq_var
            bins.append(
                BinSummary(
                    lab,
                    n,
                    float(np.sqrt(np.mean(np.sum(phys[mask] ** 2, axis=1)))),
                    phys[mask].mean(axis=0).tolist(),
                )
            )
        B = len(groups)
        k_s, k_t = m * (B - 1), B - 1
        log_s, log_t = float(stats.chi2.logsf(S, k_s)), float(stats.chi2.logsf(T, k_t))
        out.append(
            FeatureGap(
                f.name,
                f.label,
                f.unit,
                S,
                float(np.exp(log_s)),
                T,
                float(np.exp(log_t)),
                min(log_s, log_t) / np.log(10.0),
                max(_wilson_hilferty(S, k_s), _wilson_hilferty(T, k_t)),
                bins,
            )
        )
    out.sort(key=lambda g: -g.z)
    return out
