"""Robust initialisation: least-median-of-squares consensus over minimal pose triples.

A closed form on all samples is pulled away by gross outliers (a swapped sample, a detection of
the wrong target) and a bad start can trap the robust ML in a wrong minimum. When the all-sample
closed form leaves a sample more than 3x the median pose-chain cost away, or its median cost is
far above the noise (> 10, about 3x an inlier's), the solver runs:

1. ``pose_chain_cost`` measures each sample against a candidate (X, Y): the deviation of its pose
   chain ``A_i X B_i`` from Y in noise units (translation and rotation, camera lever arm included);
2. minimal subsets of 3 poses (2 independent motions) give candidates by Park-Martin; the candidate
   with the smallest *median* cost over all samples wins (LMedS: tolerates up to 50 % outliers,
   needs no threshold); up to ``max_subsets`` triples, drawn with the given seed when there are more
   (80 triples miss a clean one with probability 1e-11 at 30 % outliers, 4e-7 at 40 %);
3. samples whose cost exceeds ``3 x`` the winning median are the consensus outliers; the caller
   re-runs the closed forms on the rest and starts the ML with them weighted out (the ML decides
   the final outlier flags itself).
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
    s_r = np.hypot(np.mean(noise.camera.rot_sigma), np.mean(noise.robot.rot_sigma))
    s_t = np.hypot(np.mean(noise.camera.trans_sigma), np.mean(noise.robot.trans_sigma))
    lever = float(np.median(np.linalg.norm(B[:, :3, 3], axis=1)))  # camera rotation error * distance
    s_t = np.hypot(s_t, lever * s_r)
    return np.linalg.norm(d[:, :3], axis=1) / s_t + np.linalg.norm(d[:, 3:], axis=1) / s_r


@dataclass
class Consensus:
    """Winning minimal-subset candidate and the samples it calls outliers."""

    X: F64
    Y: F64
    outliers: NDArray[np.bool_]
    median_cost: float
    subsets_tried: int


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
    """LMedS over pose triples (see module docstring); None for fewer than ``min_samples`` samples."""
    n = M.shape[0]
    if n < min_samples:
        return None
    triples = list(combinations(range(n), 3))
    if len(triples) > max_subsets:
        rng = np.random.default_rng(seed)
        triples = [triples[k] for k in np.sort(rng.choice(len(triples), max_subsets, replace=False))]
    best: tuple[float, F64, F64] | None = None
    for t in triples:
        idx = np.array(t)
        with np.errstate(all="ignore"):
            X, Y = closed_form(setup, M[idx], B[idx], "park_martin")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            continue
        med = float(np.median(pose_chain_cost(setup, M, B, X, Y, noise)))
        if best is None or med < best[0]:
            best = (med, X, Y)
    if best is None:
        return None
    med, X, Y = best
    cost = pose_chain_cost(setup, M, B, X, Y, noise)
    return Consensus(X, Y, cost > 3.0 * med, med, len(triples))
