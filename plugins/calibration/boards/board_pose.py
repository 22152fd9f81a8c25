"""The board's pose in one image, ``T_cam_target``, with its 6x6 covariance.

Steps: the corners are undistorted with the camera model (:meth:`CameraModel.normalised`), OpenCV's
planar PnP (``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE``: both planar solutions, the one with the
smaller reprojection error kept) gives the start, and ``cv2.solvePnPRefineLM`` (Levenberg-Marquardt
on the distorted pixel residuals) refines it; the fisheye model, which OpenCV's refiner does not
take, is refined with ``scipy.optimize.least_squares`` on the same residuals.

Covariance: ``sigma² (Jᵀ J)⁻¹`` with ``J`` the Jacobian of every corner's pixel position with respect
to the pose perturbation the hand-eye solver uses for its camera measurements
(:mod:`plugins.calibration.handeye.noise`, :func:`engine.transforms.retract`): ``R' = exp([dphi]) R``,
``t' = t + dt``, both in the camera frame, ordered ``(tx, ty, tz, rx, ry, rz)`` (m, rad). So
``BoardPose.covariance`` is directly a per-sample camera covariance for the hand-eye solver. ``J``
comes from ``cv2.projectPoints``' Jacobian with respect to the translation (``d uv / d p_cam``),
chained with ``d p_cam / d(dt, dphi) = [I, -[R X]x]``. ``sigma`` is the corner noise per pixel
coordinate: given (``sigma_px``, e.g. from the intrinsic calibration) or estimated from this view's
residuals (``RSS / (2n - 6)``). The intrinsics are taken as exact here; their uncertainty is not in
this covariance.

A board whose origin cannot be told from the image (an ``ambiguous`` detection: a chessboard with
COLS + ROWS even, a symmetric circle grid, see :mod:`.spec`) is refused: its pose could be turned
by 180 degrees from one view to the next, which no later step could notice. ``allow_ambiguous``
accepts it (e.g. to look at a single view).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import hat
from plugins.calibration.boards.detect import Detection
from plugins.camera.pinhole import CameraModel

F64 = NDArray[np.float64]

__all__ = ["AmbiguousBoardError", "BoardPose", "board_pose", "pose_jacobian", "solve_pnp"]

POSE_PARAM_NAMES = ("tx", "ty", "tz", "rx", "ry", "rz")


class AmbiguousBoardError(ValueError):
    """The board's origin cannot be told from the image (see the module docstring)."""


@dataclass(frozen=True, eq=False)
class BoardPose:
    """``T_cam_target`` (4x4, m) of one view with ``covariance`` (6x6, decoupled ``(dt, dphi)`` in the
    camera frame, m and rad), the corner noise ``sigma_px`` it assumes, the reprojection residuals
    ``(n, 2)`` px and their RMS distance."""

    name: str
    T_cam_target: F64
    covariance: F64
    sigma_px: float
    residuals_px: F64
    rms_px: float
    n_points: int

    def std(self) -> F64:
        """1-sigma of ``(tx, ty, tz, rx, ry, rz)`` (m, rad)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


def _T(rvec: ArrayLike, tvec: ArrayLike) -> F64:
    import cv2

    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, float).ravel()
    return T


def solve_pnp(camera: CameraModel, image_points: ArrayLike, object_points: ArrayLike) -> F64:
    """``T_cam_target`` minimising the pixel reprojection error of the board's points (module docstring)."""
    import cv2

    img = np.asarray(image_points, float).reshape(-1, 2)
    obj = np.asarray(object_points, float).reshape(-1, 3)
    if len(img) < 4 or len(img) != len(obj):
        raise ValueError(f"a board pose needs at least 4 matched points, got {len(img)} and {len(obj)}")
    xy = camera.normalised(img)
    planar = np.allclose(obj[:, 2], 0.0)
    method = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_ITERATIVE
    eye, zero = np.eye(3), np.zeros(5)
    n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, xy.reshape(-1, 1, 2), eye, zero, flags=method)
    if n == 0:
        raise ValueError("PnP found no pose for these points")
    cands = [_T(r, t) for r, t in zip(rvecs, tvecs, strict=True)]
    T = min(cands, key=lambda c: float(np.sum((camera.project(c, obj) - img) ** 2)))
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    tvec = T[:3, 3].reshape(3, 1).copy()
    if camera.model != "fisheye":
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-12)
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, camera.K, camera.D, rvec, tvec, criteria=criteria)
        return _T(rvec, tvec)
    from scipy.optimize import least_squares

    def residual(p: F64) -> F64:
        return (camera.project(_T(p[:3], p[3:]), obj) - img).ravel()

    sol = least_squares(residual, np.r_[rvec.ravel(), tvec.ravel()], method="lm", xtol=1e-14, ftol=1e-14)
    return _T(sol.x[:3], sol.x[3:])


def pose_jacobian(camera: CameraModel, T_cam_target: ArrayLike, object_points: ArrayLike) -> F64:
    """``d(pixels) / d(dt, dphi)`` ``(2n, 6)``, rows ``u0, v0, u1, ...`` (module docstring)."""
    import cv2

    T = np.asarray(T_cam_target, float)
    obj = np.asarray(object_points, float).reshape(-1, 3)
    if camera.model == "fisheye":
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        _, Jf = cv2.fisheye.projectPoints(
            obj.reshape(-1, 1, 3), rvec, np.ascontiguousarray(T[:3, 3].reshape(3, 1)), camera.K, camera.D
        )
        Jt = np.asarray(Jf, float)[:, 11:14]
    else:
        _, J = camera.project_with_jacobian(T, obj)
        assert J is not None
        Jt = J[:, 3:6]
    RX = obj @ T[:3, :3].T
    Jt3 = Jt.reshape(-1, 2, 3)
    Jrot = -np.einsum("nij,njk->nik", Jt3, hat(RX).reshape(-1, 3, 3))
    return np.concatenate([Jt3, Jrot], axis=2).reshape(-1, 6)


def board_pose(
    detection: Detection,
    camera: CameraModel,
    *,
    sigma_px: float | None = None,
    allow_ambiguous: bool = False,
) -> BoardPose:
    """The board's pose in one detection, with its covariance (module docstring)."""
    if detection.ambiguous and not allow_ambiguous:
        raise AmbiguousBoardError(
            f"{detection.name}: the board looks the same turned by 180 degrees, so its origin (and its pose) "
            "is ambiguous; use a chessboard whose COLS + ROWS is odd, an asymmetric circle grid with an odd number "
            "of rows, or a ChArUco board"
        )
    if detection.image_size != camera.size:
        w, h = detection.image_size
        raise ValueError(
            f"{detection.name}: image {w}x{h} but the camera is calibrated for {camera.width}x{camera.height}"
        )
    T = solve_pnp(camera, detection.image_points, detection.object_points)
    if T[:3, 2] @ -T[:3, 3] <= 0:
        raise ValueError(f"{detection.name}: the pose puts the camera behind the board (mirrored points?)")
    r = camera.project(T, detection.object_points) - detection.image_points
    n = detection.n
    rss = float(np.sum(r**2))
    if sigma_px is None:
        if n <= 3:
            raise ValueError(f"{detection.name}: {n} points leave no redundancy to estimate the corner noise")
        sigma = float(np.sqrt(rss / (2 * n - 6)))
    else:
        if not (np.isfinite(sigma_px) and sigma_px > 0):
            raise ValueError(f"sigma_px must be positive, got {sigma_px}")
        sigma = float(sigma_px)
    J = pose_jacobian(camera, T, detection.object_points)
    cov = sigma**2 * np.linalg.inv(J.T @ J)
    return BoardPose(detection.name, T, 0.5 * (cov + cov.T), sigma, r, float(np.sqrt(rss / n)), n)
