"""Hand-eye judged and refined in pixels: the board's corners predicted through the robot poses.

Every view ``i`` predicts the board's pose in the camera from the robot pose ``M_i = T_base_tcp_i``,
the hand-eye transform ``X`` and the board's pose ``Y`` (:func:`problem.model_camera_poses`: eye in
hand ``B_i = X^-1 M_i^-1 Y``, ``X = T_tcp_cam``, ``Y = T_base_target``; eye to hand
``B_i = X^-1 M_i Y``, ``X = T_base_cam``, ``Y = T_tcp_target``), and the camera model projects the
board's points. This module owns:

* :func:`refine_reprojection`: ``scipy.optimize.least_squares`` over ``X``, ``Y`` (decoupled
  perturbations, :func:`engine.transforms.retract`) and optionally the intrinsics (fx, fy, cx, cy and
  the distortion coefficients), minimising every corner's pixel residual. With 12 (+ 4 + k)
  parameters that every residual depends on, the Jacobian is dense and its finite differences cost
  13-22 projections of all views: cheap, so no analytic Jacobian is written. The robot poses are
  taken as exact. Covariance ``s² (JᵀJ)⁻¹`` with ``s²`` the residuals' variance per pixel coordinate.
* :func:`holdout_rms`: leave-one-view-out. A fitting function gets the other views, returns
  ``(X, Y)``; the left-out view's corners are predicted and compared with the detected ones.
* :func:`world_spread`: each view's own estimate of the board's world pose ``A_i X B_i`` (with its
  PnP pose ``B_i``) and their RMS spread about their mean, in metres and radians.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from engine.transforms import pose_delta, retract
from plugins.solvers.boards.camera import CameraModel
from plugins.solvers.boards.detect import Detection
from plugins.solvers.handeye.problem import Setup, chain_poses, model_camera_poses

F64 = NDArray[np.float64]

__all__ = [
    "Refinement",
    "holdout_rms",
    "mean_pose",
    "predicted_pixels",
    "refine_reprojection",
    "view_residuals",
    "world_spread",
]

FitFn = Callable[[NDArray[np.int64]], tuple[F64, F64]]


@dataclass(frozen=True, eq=False)
class Refinement:
    """The pixel refinement's outcome: ``X``, ``Y``, the camera (refined or as given), covariance of
    ``(dX, dY[, intrinsics])`` and per-view RMS / max residual (px)."""

    X: F64
    Y: F64
    camera: CameraModel
    covariance: F64
    sigma_px: float
    rms_px: float
    view_rms_px: F64
    view_max_px: F64
    nfev: int
    converged: bool
    intrinsics_refined: bool
    dof: int  # residual coordinates minus parameters: the degrees of freedom of sigma_px


def _with_intrinsics(camera: CameraModel, p: F64) -> CameraModel:
    K = camera.K.copy()
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = p[:4]
    return CameraModel(camera.width, camera.height, K, p[4:], camera.model, dict(camera.extra))


def _intrinsic_vector(camera: CameraModel) -> F64:
    K = camera.K
    return np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], camera.D]


def predicted_pixels(
    setup: Setup, T_base_tcp: F64, X: F64, Y: F64, camera: CameraModel, views: Sequence[Detection]
) -> list[F64]:
    """Each view's board points projected through robot pose, hand-eye and board pose (module docstring)."""
    B = model_camera_poses(setup, np.asarray(T_base_tcp, float).reshape(-1, 4, 4), X, Y)
    return [camera.project(b, v.object_points) for b, v in zip(B, views, strict=True)]


def view_residuals(
    setup: Setup, T_base_tcp: F64, X: F64, Y: F64, camera: CameraModel, views: Sequence[Detection]
) -> list[F64]:
    """Predicted minus detected pixels ``(n_i, 2)`` per view."""
    pred = predicted_pixels(setup, T_base_tcp, X, Y, camera, views)
    return [p - v.image_points for p, v in zip(pred, views, strict=True)]


def refine_reprojection(
    setup: Setup,
    T_base_tcp: F64,
    views: Sequence[Detection],
    camera: CameraModel,
    X0: F64,
    Y0: F64,
    *,
    refine_intrinsics: bool = False,
) -> Refinement:
    """``X``, ``Y`` (and the intrinsics) minimising the corners' pixel residuals (module docstring)."""
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    if len(M) != len(views):
        raise ValueError(f"{len(M)} robot poses for {len(views)} views")
    if refine_intrinsics and camera.model == "fisheye":
        raise ValueError("refining the intrinsics of the fisheye model is not supported; give them fixed")
    k0 = _intrinsic_vector(camera)
    n_int = len(k0) if refine_intrinsics else 0

    def unpack(p: F64) -> tuple[F64, F64, CameraModel]:
        X = retract(X0, p[:6])[0]
        Y = retract(Y0, p[6:12])[0]
        cam = _with_intrinsics(camera, k0 + p[12:]) if n_int else camera
        return X, Y, cam

    def residual(p: F64) -> F64:
        X, Y, cam = unpack(p)
        return np.concatenate([r.ravel() for r in view_residuals(setup, M, X, Y, cam, views)])

    # relative steps: 1e-7 m / rad for the poses, 1e-7 of a pixel-sized intrinsic
    diff_step = np.r_[np.full(12, 1e-7), np.full(n_int, 1e-7)]
    sol = least_squares(
        residual, np.zeros(12 + n_int), method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-10,
        diff_step=diff_step, max_nfev=200,
    )  # fmt: skip
    X, Y, cam = unpack(sol.x)
    r = sol.fun.reshape(-1, 2)
    m, p = r.size, sol.x.size
    s2 = float(np.sum(r**2) / max(m - p, 1))
    J = np.asarray(sol.jac)
    cov = s2 * np.linalg.pinv(J.T @ J)
    per = view_residuals(setup, M, X, Y, cam, views)
    d = [np.linalg.norm(v, axis=1) for v in per]
    return Refinement(
        X, Y, cam, 0.5 * (cov + cov.T), float(np.sqrt(s2)),
        float(np.sqrt(np.mean(np.concatenate(d) ** 2))),
        np.array([np.sqrt(np.mean(x**2)) for x in d]), np.array([x.max() for x in d]),
        int(sol.nfev), bool(sol.success), bool(n_int), int(m - p),
    )  # fmt: skip


def holdout_rms(setup: Setup, T_base_tcp: F64, views: Sequence[Detection], camera: CameraModel, fit: FitFn) -> F64:
    """Per view: the RMS distance (px) of its corners predicted by a fit to the other views."""
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    n = len(views)
    out = np.empty(n)
    for k in range(n):
        train = np.array([i for i in range(n) if i != k], dtype=np.int64)
        X, Y = fit(train)
        r = view_residuals(setup, M[k : k + 1], X, Y, camera, [views[k]])[0]
        out[k] = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    return out


def mean_pose(T: F64) -> F64:
    """The mean of poses ``(n, 4, 4)``: mean translation, chordal L2 mean rotation."""
    T = np.asarray(T, float).reshape(-1, 4, 4)
    out = np.eye(4)
    out[:3, :3] = Rotation.from_matrix(T[:, :3, :3]).mean().as_matrix()
    out[:3, 3] = T[:, :3, 3].mean(axis=0)
    return out


def world_spread(setup: Setup, T_base_tcp: F64, T_cam_target: F64, X: F64) -> tuple[float, float, F64]:
    """RMS spread (m, rad) of the views' own board poses ``A_i X B_i`` about their mean, and the mean."""
    Ys = chain_poses(setup, np.asarray(T_base_tcp, float), X, np.asarray(T_cam_target, float))
    Ym = mean_pose(Ys)
    d = pose_delta(Ys, np.broadcast_to(Ym, Ys.shape))
    t = float(np.sqrt(np.mean(np.sum(d[:, :3] ** 2, axis=1))))
    r = float(np.sqrt(np.mean(np.sum(d[:, 3:] ** 2, axis=1))))
    return t, r, Ym
