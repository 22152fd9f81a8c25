"""Is structure left in the reprojection residuals? Two tests that do not use a noise estimate.

**Across views, fixed in the image** (:func:`residual_structure`). The image is cut into an 8 x 6
grid of cells; ``f_v(c)`` is the sum of view ``v``'s residual vectors (detected - projected, px) of
the corners in cell ``c``. A systematic error the model misses (a lens term it lacks, a bias of the
detector) pulls the residuals of every view the same way where it acts, so the per-cell sums add up
coherently over views; noise does not. Statistic: ``T = sum_c |sum_v f_v(c)|^2``. Its null
distribution is by **sign flipping whole views** (a random sign per view, 9999 seeded draws:
p-values down to 1e-4): under H0 each view's residual field is symmetric noise, so every sign
pattern is as likely as the observed one (a permutation test: exact, whatever the noise level or its
correlation within a view). The residuals are those of the model fitted to all views, which removes
the part of any field the model can absorb (the test is conservative for that reason).

``where`` reports the cells whose mean residual is largest (px, with the cell's image-centre
position), i.e. where an effect outside the model concentrates.

**Within a view, smooth over the board** (:func:`neighbour_structure`). An error that moves with the
board (a board that is not flat, a camera moving during a rolling-shutter exposure) is not fixed in
the image, but in each view it is smooth: neighbouring corners' residuals point the same way, where
independent noise does not. Statistic: ``S = sum over neighbouring corner pairs (i, j) of r_i . r_j``
(neighbours: board points one grid step apart, per view); under H0 (independent, symmetric corner
noise) flipping each corner's sign is exchangeable, so ``S`` has mean 0 and variance
``sum (r_i . r_j)^2`` over the flips: ``z = S / sqrt(sum (r_i . r_j)^2)``, one-sided normal p-value.
A fitted model makes neighbouring residuals slightly *negatively* correlated (the smooth part of the
noise is absorbed), so the test is conservative. ``where`` lists the views with the largest
correlation. A detector whose errors are themselves correlated between neighbouring corners (blur,
uneven light) fails it too: that is structure the camera model cannot explain either.

The workflow takes the smaller p-value of the two, Bonferroni-corrected (x 2).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.boards.detect import Detection

F64 = NDArray[np.float64]

__all__ = ["CELL_GRID", "StructureTest", "neighbour_structure", "residual_structure"]

CELL_GRID = (8, 6)
N_FLIPS = 9999


@dataclass(frozen=True)
class StructureTest:
    """The sign-flip test of the residual field: statistic, p-value, and the cells it concentrates in."""

    statistic: float
    p_value: float
    coherent_share: float  # T over the sum of squared per-view cell sums: ~1/n_views for pure noise
    where: list[dict[str, Any]]

    test: str = "sign flip of whole views over an 8x6 image grid of residual sums"

    def to_dict(self) -> dict[str, Any]:
        return {
            "test": self.test,
            "statistic": self.statistic,
            "p_value": self.p_value,
            "coherent_share": self.coherent_share,
            "where": self.where,
        }


def _cell_sums(views: Sequence[Detection], residuals: Sequence[F64], size: tuple[int, int]) -> F64:
    gx, gy = CELL_GRID
    w, h = size
    out = np.zeros((len(views), gx * gy, 2))
    for k, (v, r) in enumerate(zip(views, residuals, strict=True)):
        ix = np.clip((v.image_points[:, 0] / w * gx).astype(int), 0, gx - 1)
        iy = np.clip((v.image_points[:, 1] / h * gy).astype(int), 0, gy - 1)
        np.add.at(out[k], iy * gx + ix, r)
    return out


def residual_structure(
    views: Sequence[Detection], residuals: Sequence[F64], size: tuple[int, int], seed: int = 0, top: int = 3
) -> StructureTest:
    """The test of the module docstring on *residuals* (one (n, 2) array per view)."""
    f = _cell_sums(views, residuals, size)  # (views, cells, 2)
    total = f.sum(axis=0)
    stat = float(np.sum(total**2))
    signs = np.random.default_rng(seed).choice((-1.0, 1.0), size=(N_FLIPS, len(views)))
    flipped = np.einsum("bv,vcj->bcj", signs, f)
    null = np.sum(flipped**2, axis=(1, 2))
    p = float((1 + np.sum(null >= stat)) / (N_FLIPS + 1))
    energy = float(np.sum(f**2))
    gx, gy = CELL_GRID
    w, h = size
    counts = np.zeros(gx * gy)
    for v in views:
        ix = np.clip((v.image_points[:, 0] / w * gx).astype(int), 0, gx - 1)
        iy = np.clip((v.image_points[:, 1] / h * gy).astype(int), 0, gy - 1)
        np.add.at(counts, iy * gx + ix, 1)
    mean = total / np.maximum(counts, 1)[:, None]
    order = np.argsort(-np.linalg.norm(mean, axis=1))[:top]
    where = [
        {
            "cell_centre_px": [float((c % gx + 0.5) * w / gx), float((c // gx + 0.5) * h / gy)],
            "mean_residual_px": mean[c].tolist(),
            "n_corners": int(counts[c]),
        }
        for c in order
        if counts[c] > 0
    ]
    return StructureTest(stat, p, stat / energy if energy > 0 else 0.0, where)


def _neighbour_pairs(points: F64) -> NDArray[np.int64]:
    """Index pairs of board points one grid step apart (within 1.05 x the smallest spacing)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points[:, :2])
    d, _ = tree.query(points[:, :2], k=2)
    step = float(np.min(d[:, 1])) if len(points) > 1 else 0.0
    if step <= 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.asarray(sorted(tree.query_pairs(1.05 * step)), dtype=np.int64).reshape(-1, 2)


def neighbour_structure(views: Sequence[Detection], residuals: Sequence[F64], top: int = 3) -> StructureTest:
    """The within-view neighbour test of the module docstring on *residuals* (one (n, 2) per view)."""
    stat, var = 0.0, 0.0
    per_view = []
    for v, r in zip(views, residuals, strict=True):
        pairs = _neighbour_pairs(v.object_points)
        if not len(pairs):
            continue
        prod = np.sum(r[pairs[:, 0]] * r[pairs[:, 1]], axis=1)
        stat += float(prod.sum())
        var += float(np.sum(prod**2))
        norm = float(np.sum(r**2))
        per_view.append((float(prod.sum()) / norm if norm > 0 else 0.0, v.name))
    from scipy.stats import norm as normal

    z = stat / np.sqrt(var) if var > 0 else 0.0
    p = float(normal.sf(z))
    per_view.sort(reverse=True)
    where = [{"view": name, "neighbour_correlation": c} for c, name in per_view[:top]]
    total = float(sum(np.sum(r**2) for r in residuals))
    return StructureTest(
        float(z),
        p,
        stat / total if total > 0 else 0.0,
        where,
        "neighbour correlation within views (sign flips of corners)",
    )
