"""k-fold cross-validation over depth captures: each capture's held-out squared range error under a
depth model fitted to the other folds' captures.

The folds are the camera workflow's (:func:`plugins.model_gap.camera.crossval.view_folds`: a seeded
permutation of the captures), the same for every model of a run, so two models' held-out errors
pair capture by capture; the naming rule is the camera workflow's too
(:mod:`plugins.model_gap.camera.selection`), which reads a model's held-out errors through ``sse``,
``n_points`` and ``rms_px``: :class:`DepthCrossValidation` offers them, ``rms_px`` being the held-out
RMS in the depth gap's unit, millimetres (a capture is the unit: its pixels share the target's pose
and whatever the sensor does at that range). A held-out capture's plane is refitted with the
model's effects held when the plane is fitted per capture (:func:`.fitting.residuals_under`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.camera.crossval import view_folds
from plugins.model_gap.depth.catalog import DepthEffect
from plugins.model_gap.depth.data import Pixels
from plugins.model_gap.depth.fitting import DepthFit, fit_model, residuals_under

F64 = NDArray[np.float64]

__all__ = ["DepthCrossValidation", "capture_folds", "cross_validate"]

capture_folds = view_folds


@dataclass(frozen=True, eq=False)
class DepthCrossValidation:
    """Held-out scores of one model: per capture the squared range error sum (m^2) and the pixel
    count, every pixel's held-out residual (m) and each fold's fit."""

    effects: tuple[DepthEffect, ...]
    sse: F64  # (n_captures,)
    n_points: NDArray[np.int64]  # (n_captures,)
    residual: F64  # (n_pixels,) held-out
    fold_fits: tuple[DepthFit, ...]

    @property
    def rms_mm(self) -> float:
        """Held-out RMS range error per pixel (mm)."""
        return float(1e3 * np.sqrt(self.sse.sum() / max(int(self.n_points.sum()), 1)))

    @property
    def rms_px(self) -> float:
        """:attr:`rms_mm` under the name the camera selection reads (its unit is the caller's: mm)."""
        return self.rms_mm

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]


def cross_validate(
    px: Pixels,
    effects: Sequence[DepthEffect],
    folds: Sequence[NDArray[np.int64]],
    weights: F64,
    period: float,
) -> DepthCrossValidation:
    """Held-out errors of the model made of *effects* over *folds* (index arrays of captures)."""
    effects = tuple(effects)
    n = px.n_captures
    sse = np.zeros(n)
    counts = np.bincount(px.capture, minlength=n).astype(np.int64)
    held = np.zeros(len(px.capture))
    fits = []
    for test in folds:
        mask = px.of(test)
        fit = fit_model(px, ~mask, effects, weights, period)
        fits.append(fit)
        sub = px.take(mask)
        held[mask] = residuals_under(sub, fit, weights[mask], period)
    np.add.at(sse, px.capture, held**2)
    return DepthCrossValidation(effects, sse, counts, held, tuple(fits))
