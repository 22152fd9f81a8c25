"""Is structure left in the range residuals? Two sign-flip tests that use no noise estimate.

**Fixed in the image** (:func:`image_structure`): the camera workflow's own test
(:func:`plugins.model_gap.camera.structure.residual_structure`: per-capture residual sums over an
8 x 6 grid of image cells, the statistic ``sum_c |sum_v f_v(c)|^2``, its null by flipping the sign
of whole captures, 9999 seeded draws). A per-pixel bias the model lacks adds up over captures where
it acts; noise and per-capture errors (a target pose a little off) do not. Each pixel is handed over
as a "corner" at its image position with its range residual as the first component of the vector.

**Fixed in range** (:func:`range_structure`): the same statistic over 8 bins of the predicted range
(quantiles of all pixels' ranges) instead of image cells: a range error the model lacks (a scale, a
bias, a wiggle outside the catalog's period) has the same sign at the same range in every capture.

Both are exact permutation tests whatever the noise's level or its correlation within a capture (a
stereo camera's noise is correlated over its matching window: a per-pixel test would not be). The
workflow takes the smaller p-value, Bonferroni-corrected (x 2). ``where`` lists the cells or range
bins whose mean residual is largest (mm).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.camera.structure import N_FLIPS, StructureTest, residual_structure
from plugins.model_gap.depth.data import Pixels

F64 = NDArray[np.float64]

__all__ = ["RANGE_BINS", "DepthStructure", "image_structure", "range_structure", "structure_of"]

RANGE_BINS = 8


@dataclass(frozen=True)
class _AsView:
    """A capture's pixels as the camera structure test reads a board view (``image_points``)."""

    image_points: F64


def image_structure(px: Pixels, residual: F64, seed: int = 0) -> StructureTest:
    """The image-field test of the module docstring; ``where`` in mm (``mean_residual_mm``)."""
    views, res = [], []
    for k in range(px.n_captures):
        m = px.capture == k
        views.append(_AsView(np.column_stack((px.u[m], px.v[m]))))
        res.append(np.column_stack((residual[m], np.zeros(int(m.sum())))))
    t = residual_structure(views, res, px.size, seed)  # type: ignore[arg-type]
    where = [
        {
            "cell_centre_px": w["cell_centre_px"],
            "mean_residual_mm": 1e3 * w["mean_residual_px"][0],
            "n_pixels": w["n_corners"],
        }
        for w in t.where
    ]
    return StructureTest(
        t.statistic, t.p_value, t.coherent_share, where, "sign flip of whole captures over an 8x6 image grid"
    )


def range_structure(px: Pixels, residual: F64, seed: int = 0, top: int = 3) -> StructureTest:
    """The range-bin test of the module docstring."""
    edges = np.quantile(px.r_ref, np.linspace(0.0, 1.0, RANGE_BINS + 1))
    b = np.clip(np.searchsorted(edges, px.r_ref, side="right") - 1, 0, RANGE_BINS - 1)
    f = np.zeros((px.n_captures, RANGE_BINS))
    np.add.at(f, (px.capture, b), residual)
    total = f.sum(axis=0)
    stat = float(np.sum(total**2))
    signs = np.random.default_rng(seed).choice((-1.0, 1.0), size=(N_FLIPS, px.n_captures))
    null = np.sum((signs @ f) ** 2, axis=1)
    p = float((1 + np.sum(null >= stat)) / (N_FLIPS + 1))
    energy = float(np.sum(f**2))
    counts = np.bincount(b, minlength=RANGE_BINS)
    mean = total / np.maximum(counts, 1)
    where = [
        {
            "range_mm": [float(1e3 * edges[c]), float(1e3 * edges[c + 1])],
            "mean_residual_mm": float(1e3 * mean[c]),
            "n_pixels": int(counts[c]),
        }
        for c in np.argsort(-np.abs(mean))[:top]
        if counts[c] > 0
    ]
    share = stat / energy if energy > 0 else 0.0
    return StructureTest(stat, p, share, where, "sign flip of whole captures over 8 range bins")


@dataclass(frozen=True)
class DepthStructure:
    """Both tests of one model's residuals and their combined p-value (the smaller, Bonferroni x 2)."""

    image_field: StructureTest
    range_bins: StructureTest

    @property
    def p_value(self) -> float:
        return min(1.0, 2.0 * min(self.image_field.p_value, self.range_bins.p_value))

    def describe(self) -> str:
        """Where the structure is, in words (the test with the smaller p-value)."""
        if self.image_field.p_value <= self.range_bins.p_value:
            w = self.image_field.where[0] if self.image_field.where else {}
            return (
                f"a range error fixed in the image, largest near pixel "
                f"({', '.join(f'{c:.0f}' for c in w.get('cell_centre_px', ()))}) "
                f"({w.get('mean_residual_mm', float('nan')):+.2f} mm)"
            )
        w = self.range_bins.where[0] if self.range_bins.where else {}
        lo, hi = w.get("range_mm", (float("nan"), float("nan")))
        return (
            f"a range error fixed in range, largest at ranges {lo:.0f}-{hi:.0f} mm "
            f"({w.get('mean_residual_mm', float('nan')):+.2f} mm)"
        )

    def advice(self) -> str:
        """What to measure to find the effect (the test with the smaller p-value)."""
        if self.image_field.p_value <= self.range_bins.p_value:
            return (
                "capture the target so that it fills the image (its corners too) at several distances; a pattern "
                "outside the catalog (higher order, off-centre) or a target that is not flat fits there"
            )
        return (
            "capture the target at more distances, closely spaced over the working range (every 2-5 cm), "
            "to resolve a range error outside the catalog (a wiggle of another period, a range-dependent step)"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "p_value": self.p_value,
            "image_field": self.image_field.to_dict(),
            "range_bins": self.range_bins.to_dict(),
        }


def structure_of(px: Pixels, residual: F64, seed: int) -> DepthStructure:
    """Both structure tests on *residual* (one value per pixel of *px*)."""
    return DepthStructure(image_structure(px, residual, seed), range_structure(px, residual, seed))
