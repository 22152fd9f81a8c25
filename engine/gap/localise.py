"""Where the gap concentrates: residuals binned along each feature (joint angle, torque, time ...).

For a feature the samples are split into bins (quantiles for continuous features, the values for
categorical ones such as an approach direction). Two statistics compare the bins, both chi-square
distributed if the residuals are pure noise matching the specification (whitened, unit variance):

* **mean shift** ``S = sum_b n_b |mean_b(w)|^2 ~ chi2(m B)``: the residual has a systematic part
  that changes along the feature (backlash flips with the direction, compliance grows with the
  torque, drift with time);
* **spread** ``T = sum_b n_b (mean_b(|w|^2) - m)^2 / (2 m) ~ chi2(B)`` (approximately): the residual's
  size changes along the feature without a consistent direction (latency grows with speed).

Features are ranked by the smaller p-value; each bin reports its sample count, range and 3-D RMS
and mean residual in physical units, so a reader sees *where* the model disagrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .interfaces import Feature, Linearisation


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
    v = f.values
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
            mean_w = w[mask].mean(axis=0)
            S += n * float(mean_w @ mean_w)
            T += n * (float(np.mean(np.sum(w[mask] ** 2, axis=1))) - m) ** 2 / (2 * m)
            bins.append(
                BinSummary(
                    lab,
                    n,
                    float(np.sqrt(np.mean(np.sum(phys[mask] ** 2, axis=1)))),
                    phys[mask].mean(axis=0).tolist(),
                )
            )
        B = len(groups)
        log_s, log_t = float(stats.chi2.logsf(S, m * B)), float(stats.chi2.logsf(T, B))
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
                max(_wilson_hilferty(S, m * B), _wilson_hilferty(T, B)),
                bins,
            )
        )
    out.sort(key=lambda g: -g.z)
    return out
