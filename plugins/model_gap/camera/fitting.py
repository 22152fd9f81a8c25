"""OpenCV fits of one camera model (a set of free distortion coefficients) to board views, and the
reprojection errors of views the fit did not see.

:func:`fit_views` runs ``cv2.calibrateCamera`` with the flags of :func:`.catalog.calibrate_flags`
(optionally started from an earlier fit's intrinsics: ``CALIB_USE_INTRINSIC_GUESS``) and keeps the
intrinsics, the 14-coefficient distortion vector, each view's pose and its squared reprojection errors.
:func:`held_out_errors` scores views left out of a fit: each view's board pose is solved from its own
corners with the fitted intrinsics (``cv2.solvePnP``, refined by ``cv2.solvePnPRefineLM``), then its
corners are reprojected (``cv2.projectPoints``); only the 6 pose parameters are fitted to that view.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.boards.detect import Detection
from plugins.model_gap.camera.catalog import BOARD_POINTS, COEFFICIENTS, calibrate_flags

F64 = NDArray[np.float64]

__all__ = ["CameraModelFit", "fit_nested", "fit_views", "fixed_board_point", "held_out_errors", "project_view"]

_CRITERIA = (3, 100, 1e-10)  # cv2.TERM_CRITERIA_COUNT | EPS


@dataclass(frozen=True, eq=False)
class CameraModelFit:
    """A fit of the model with coefficients ``free``: ``K`` (3x3), ``D`` (14, OpenCV's order), the
    pose ``(rvec, tvec)`` of each view and each view's residuals ``detected - projected`` (n, 2) px;
    ``board_points`` (n, 3) m: the released board's points (None: the board as specified)."""

    free: frozenset[str]
    K: F64
    D: F64
    rvecs: tuple[F64, ...]
    tvecs: tuple[F64, ...]
    residuals: tuple[F64, ...]
    board_points: F64 | None = None

    @property
    def rss(self) -> float:
        return float(sum(np.sum(r**2) for r in self.residuals))

    @property
    def n_points(self) -> int:
        return int(sum(len(r) for r in self.residuals))

    @property
    def rms_px(self) -> float:
        """OpenCV's RMS: the root mean square reprojection *distance* per corner."""
        return float(np.sqrt(self.rss / max(self.n_points, 1)))

    def coefficients(self) -> dict[str, float]:
        """The fitted value of every free distortion coefficient, by name."""
        return {n: float(v) for n, v in zip(COEFFICIENTS, self.D, strict=True) if n in self.free}

    def points_of(self, view: Detection) -> F64:
        """The board points *view*'s corners are projected from under this fit."""
        return view.object_points if self.board_points is None else self.board_points


def _cv_points(views: Sequence[Detection]) -> tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]]:
    obj = [np.asarray(v.object_points, np.float32).reshape(-1, 1, 3) for v in views]
    img = [np.asarray(v.image_points, np.float32).reshape(-1, 1, 2) for v in views]
    return obj, img


def project_view(K: F64, D: F64, rvec: F64, tvec: F64, object_points: F64) -> F64:
    """``cv2.projectPoints`` of the board points (n, 3) with the full distortion vector: (n, 2) px."""
    import cv2

    uv, _ = cv2.projectPoints(np.asarray(object_points, float).reshape(-1, 1, 3), rvec, tvec, K, D)
    return np.asarray(uv, float).reshape(-1, 2)


def _full(D: NDArray[np.float64]) -> F64:
    out = np.zeros(len(COEFFICIENTS))
    d = np.asarray(D, float).ravel()[: len(COEFFICIENTS)]
    out[: d.size] = d
    return out


def _output_size(flags: int) -> int:
    """The length of the distortion vector ``cv2.calibrateCamera`` returns for *flags*."""
    import cv2

    if flags & cv2.CALIB_TILTED_MODEL:
        return 14
    if flags & cv2.CALIB_THIN_PRISM_MODEL:
        return 12
    return 8 if flags & cv2.CALIB_RATIONAL_MODEL else 5


def fit_views(
    views: Sequence[Detection], size: tuple[int, int], free: frozenset[str], guess: CameraModelFit | None = None
) -> CameraModelFit:
    """``cv2.calibrateCamera`` of the model with the coefficients *free* to *views* (``guess``: start
    from that fit's K and D; coefficients it did not fit start at 0). Raises what OpenCV raises."""
    import cv2

    obj, img = _cv_points(views)
    flags = calibrate_flags(free)
    K0, D0 = None, None
    if guess is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
        K0 = guess.K.copy()
        D0 = np.where([c in guess.free for c in COEFFICIENTS], guess.D, 0.0)[: _output_size(flags)].reshape(-1, 1)
    points: F64 | None = None
    out: Any
    if BOARD_POINTS in free and guess is not None and guess.board_points is not None:
        # the board as the warm fit released it, held: OpenCV's fit of a non-planar rig (needs the guess)
        points = guess.board_points
        obj = [np.asarray(points, np.float32).reshape(-1, 1, 3) for _ in views]
        out = cv2.calibrateCamera(obj, img, size, K0, D0, flags=flags, criteria=_CRITERIA)  # type: ignore[call-overload]
    elif BOARD_POINTS in free:
        fixed = fixed_board_point(views)
        # (OpenCV 4.14's solver refuses an intrinsic guess with released points: OpenCV's own start)
        flags &= ~cv2.CALIB_USE_INTRINSIC_GUESS
        out = cv2.calibrateCameraRO(obj, img, size, fixed, None, None, flags=flags, criteria=_CRITERIA)  # type: ignore[call-overload]
        points = np.asarray(out[5], float).reshape(-1, 3)
    else:
        out = cv2.calibrateCamera(obj, img, size, K0, D0, flags=flags, criteria=_CRITERIA)  # type: ignore[call-overload]
    K: F64 = np.asarray(out[1], float)
    D14 = _full(np.asarray(out[2], float))
    rv = tuple(np.asarray(r, float).reshape(3, 1) for r in out[3])
    tv = tuple(np.asarray(t, float).reshape(3, 1) for t in out[4])
    res = tuple(
        _residual(v.image_points, project_view(K, D14, r, t, v.object_points if points is None else points))
        for v, r, t in zip(views, rv, tv, strict=True)
    )
    return CameraModelFit(free, K, D14, rv, tv, res, points)


def _residual(detected: F64, projected: F64) -> F64:
    """``detected - projected`` (n, 2) px."""
    return np.asarray(detected, float) - np.asarray(projected, float)


def fixed_board_point(views: Sequence[Detection]) -> int:
    """``iFixedPoint`` of ``cv2.calibrateCameraRO``: the last point of the board's first row (OpenCV
    also holds the first point, and the last one's height). ValueError unless every view has the
    same points."""
    ids = views[0].ids
    if any(len(v.ids) != len(ids) or np.any(v.ids != ids) for v in views):
        raise ValueError("releasing the board points needs every view to see the whole board (the same points)")
    p = views[0].object_points
    row = np.flatnonzero(np.abs(p[:, 1] - p[0, 1]) < 1e-9)
    k = int(row[np.argmax(np.abs(p[row, 0] - p[0, 0]))])
    return k if 1 <= k <= len(p) - 2 else len(p) // 2


def fit_nested(
    views: Sequence[Detection], size: tuple[int, int], free: frozenset[str], warm: CameraModelFit | None
) -> CameraModelFit:
    """The fit started from *warm* (a model with fewer coefficients on the same views); when it ends
    above the warm model's own error (a model with more coefficients fits its views at least as well:
    the solver stopped in a worse minimum), OpenCV's own initialisation is tried too, the better kept."""
    fit = fit_views(views, size, free, warm)
    if warm is not None and fit.rss > warm.rss * (1.0 + 1e-9):
        cold = fit_views(views, size, free)
        fit = cold if cold.rss < fit.rss else fit
    return fit


def held_out_errors(fit: CameraModelFit, views: Sequence[Detection]) -> list[F64]:
    """Each view's residuals (n, 2) px under *fit*'s intrinsics, its pose solved from its own corners."""
    import cv2

    out: list[F64] = []
    for v in views:
        obj = np.asarray(fit.points_of(v), float).reshape(-1, 1, 3)
        img = np.asarray(v.image_points, float).reshape(-1, 1, 2)
        ok, rvec, tvec = cv2.solvePnP(obj, img, fit.K, fit.D, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise ValueError(f"{v.name}: no board pose with the fitted camera (solvePnP failed)")
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, fit.K, fit.D, rvec, tvec)
        uv = project_view(fit.K, fit.D, np.asarray(rvec, float), np.asarray(tvec, float), fit.points_of(v))
        out.append(_residual(v.image_points, uv))
    return out
