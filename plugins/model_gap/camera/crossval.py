"""k-fold cross-validation over board views: each view's held-out squared reprojection error under a
camera model fitted to the other folds' views.

The folds are the same for every model of a run (seeded permutation of the views), so two models'
held-out errors pair view by view (:mod:`.selection` tests the pairs). A view is the unit because
the corners of one view share their board pose and much of the detector's error; a fold's fit can
start from the current model's fit of the same fold (``warm``), which OpenCV's solver needs far
fewer iterations from, and which saw no held-out view either.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.boards.detect import Detection
from plugins.model_gap.camera.fitting import CameraModelFit, fit_nested, held_out_errors

F64 = NDArray[np.float64]

__all__ = ["CrossValidation", "cross_validate", "view_folds"]


def view_folds(n_views: int, k: int, seed: int) -> list[NDArray[np.int64]]:
    """*k* folds (index arrays) of a seeded permutation of ``range(n_views)``, sizes differing by <= 1."""
    if k < 2 or k > n_views:
        raise ValueError(f"cross-validation needs 2 <= folds <= views, got {k} folds for {n_views} views")
    order = np.random.default_rng(seed).permutation(n_views)
    return [np.sort(f).astype(np.int64) for f in np.array_split(order, k)]


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """Held-out scores of one model: per view the squared reprojection error sum (px^2), the corner
    count and the residuals, and each fold's training fit."""

    free: frozenset[str]
    sse: F64  # (n_views,)
    n_points: NDArray[np.int64]  # (n_views,)
    residuals: tuple[F64, ...]
    fold_fits: tuple[CameraModelFit, ...]

    @property
    def rms_px(self) -> float:
        """Held-out RMS reprojection distance per corner (px)."""
        return float(np.sqrt(self.sse.sum() / max(int(self.n_points.sum()), 1)))


def cross_validate(
    views: Sequence[Detection],
    size: tuple[int, int],
    free: frozenset[str],
    folds: Sequence[NDArray[np.int64]],
    warm: CrossValidation | None = None,
) -> CrossValidation:
    """Held-out errors of the model with coefficients *free* over *folds* (``warm``: start each fold's
    fit from that model's fit of the same fold)."""
    n = len(views)
    sse = np.zeros(n)
    counts = np.zeros(n, dtype=np.int64)
    residuals: list[F64 | None] = [None] * n
    fits = []
    for k, test in enumerate(folds):
        held = set(test.tolist())
        train = [v for i, v in enumerate(views) if i not in held]
        fit = fit_nested(train, size, free, None if warm is None else warm.fold_fits[k])
        fits.append(fit)
        for i, r in zip(test, held_out_errors(fit, [views[i] for i in test]), strict=True):
            sse[i], counts[i], residuals[i] = float(np.sum(r**2)), len(r), r
    return CrossValidation(free, sse, counts, tuple(r for r in residuals if r is not None), tuple(fits))
