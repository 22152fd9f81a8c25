"""Robust initialisation: least-quantile-of-squares consensus over minimal pose triples.

A closed form on all samples is pulled away by gross outliers (a swapped sample, a detection of
the wrong target) and a bad start can trap the robust ML in a wrong minimum. When the all-sample
closed form leaves a sample more than 3x the median pose-chain cost away, or its median cost is
far above the noise (> 10, about 3x an inlier's), the solver runs:

1. ``pose_chain_cost`` measures each sample against a candidate (X, Y): the deviation of its pose
   chain ``A_i X B_i`` from Y in noise units (translation and rotation, camera lever arm included;
   with per-sample camera covariances each sample in its own camera noise's units);
2. minimal subsets of 3 poses (2 independent motions) give candidates by Park-Martin; the candidate
   with the smallest ``QUANTILE`` (40 %) order statistic of the cost over all samples wins (least
   quantile of squares, Rousseeuw & Leroy 1987, *Robust Regression and Outlier Detection*: with
   the 40 % quantile up to 60 % outliers leave the statistic among the inliers, where the median
   sits on the border at 50 %); up to ``max_subsets`` distinct triples, drawn with the given seed
   when there are more (80 miss a clean one with probability 1e-11 at 30 % outliers, 2e-5 at 50 %);
3. the inliers' cost scale is the median cost of the samples within ``3 x`` that order statistic;
   samples beyond ``3 x`` the scale are the consensus outliers. The caller re-runs the closed forms
   on the rest and starts the ML with them weighted out (the ML decides the final flags itself).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from engine.transforms import pose_delta
from plugins.calibration.handeye.closed_form import closed_form
from plugins.calibration.handeye.noise import NoiseModel
from plugins.calibration.handeye.problem import Setup, chain_poses

F64 = NDArray[np.float64]

__all__ = ["Consensus", "lmeds_consensus", "pose_chain_cost"]


def pose_chain_cost(setup: Setup, M: F64, B: F64, X: F64, Y: F64, noise: NoiseModel) -> F64:
    """Per-sample pose-chain deviation from Y in noise units (dimensionless, ~3 for inliers)."""
    d = pose_delta(chain_poses(setup, M, X, B), np.broadcast_to(Y, M.shape))
    cam = noise.camera_sigmas_per_sample(M.shape[0])  # (n, 6): (tx, ty, tz, rx, ry, rz)
    s_r = np.hypot(np.mean(cam[:, 3:], axis=1), np.mean(noise.robot.rot_sigma))
    s_t = np.hypot(np.mean(cam[:, :3], axis=1), np.mean(noise.robot.trans_sigma))
    lever = float(np.median(np.linalg.norm(B[:, :3, 3], axis=1)))  # camera rotation error * distance
    s_t = np.hypot(s_t, lever * s_r)
    return np.linalg.norm(d[:, :3], axis=1) / s_t + np.linalg.norm(d[:, 3:], axis=1) / s_r


@dataclass
class Consensus:
    """Winning minimal-subset candidate and the samples it calls outliers."""

    X: F64
    Y: F64
    outliers: NDArray[np.bool_]
    median_cost: float  # the inliers' cost scale (module docstring, step 3)
    subsets_tried: int


QUANTILE = 0.4  # the order statistic the candidates are ranked by (module docstring, step 2)


def _triples(n: int, max_subsets: int, seed: int) -> list[tuple[int, int, int]]:
    """Every triple of ``n`` samples, or ``max_subsets`` distinct ones drawn with *seed*."""
    total = n * (n - 1) * (n - 2) // 6
    if total <= max_subsets:
        return list(combinations(range(n), 3))
    rng = np.random.default_rng(seed)
    picked: set[tuple[int, int, int]] = set()
    while len(picked) < max_subsets:
        a, b, c = sorted(int(k) for k in rng.choice(n, 3, replace=False))
        picked.add((a, b, c))
    return sorted(picked)


def lmeds_consensus(
    setup: Setup,
    M: F64,
    B: F64,
    noise: NoiseModel,
    *,
    max_subsets: int = 80,
    seed: int = 0,
    min_samples: int = 6,
) -> Consensus | None:
    """Least-quantile consensus over pose triples (module docstring); None for fewer than
    ``min_samples`` samples."""
    n = M.shape[0]
    if n < min_samples:
        return None
    triples = _triples(n, max_subsets, seed)
    best: tuple[float, F64, F64] | None = None
    for t in triples:
        idx = np.array(t)
        with np.errstate(all="ignore"):
            X, Y = closed_form(setup, M[idx], B[idx], "park_martin")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            continue
        q = float(np.quantile(pose_chain_cost(setup, M, B, X, Y, noise), QUANTILE))
        if best is None or q < best[0]:
            best = (q, X, Y)
    if best is None:
        return None
    q, X, Y = best
    cost = pose_chain_cost(setup, M, B, X, Y, noise)
    scale = float(np.median(cost[cost <= 3.0 * q]))
    return Consensus(X, Y, cost > 3.0 * scale, scale, len(triples))


MIN_GROUP = 5  # samples that must agree among themselves to be a second calibration


def second_group(
    setup: Setup, M: F64, B: F64, outliers: NDArray[np.bool_], X: F64, Y: F64, noise: NoiseModel
) -> NDArray[np.bool_]:
    """The outliers that agree among themselves on one other calibration (the target or the camera
    moved between samples): started from the consensus of the outliers alone, refitted (Park-Martin)
    on those of them within 3x the inliers' cost scale under (X, Y), three times; a group when at least
    ``MIN_GROUP`` remain. All False when there is no such group."""
    none = np.zeros(len(outliers), dtype=bool)
    out = np.flatnonzero(outliers)
    if len(out) < MIN_GROUP:
        return none
    inlier_scale = float(np.median(pose_chain_cost(setup, M[~outliers], B[~outliers], X, Y, noise.take(~outliers))))
    noise_out = noise.take(out)
    c = lmeds_consensus(setup, M[out], B[out], noise_out, min_samples=MIN_GROUP)
    if c is None:
        return none
    X2, Y2 = c.X, c.Y
    for _ in range(3):
        grp = pose_chain_cost(setup, M[out], B[out], X2, Y2, noise_out) <= 3.0 * inlier_scale
        if np.count_nonzero(grp) < MIN_GROUP:
            return none
        with np.errstate(all="ignore"):
            X2, Y2 = closed_form(setup, M[out[grp]], B[out[grp]], "park_martin")
        if not (np.all(np.isfinite(X2)) and np.all(np.isfinite(Y2))):
            return none
    none[out[grp]] = True
    return none
