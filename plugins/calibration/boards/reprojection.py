"""Hand-eye judged and refined in pixels: the board's corners predicted through the robot poses.

Every view ``i`` predicts the board's pose in the camera from the robot pose ``M_i = T_base_tcp_i``,
the hand-eye transform ``X`` and the board's pose ``Y`` (:func:`problem.model_camera_poses`: eye in
hand ``B_i = X^-1 M_i^-1 Y``, ``X = T_tcp_cam``, ``Y = T_base_target``; eye to hand
``B_i = X^-1 M_i Y``, ``X = T_base_cam``, ``Y = T_tcp_target``), and the camera model projects the
board's points. This module owns:

* :func:`refine_reprojection`: least squares over ``X``, ``Y`` (decoupled perturbations,
  :func:`engine.transforms.retract`) and optionally the intrinsics (fx, fy, cx, cy and the
  distortion coefficients), minimising every corner's pixel residual. With ``robot_noise``, every
  robot pose gets a 6-dof correction ``d_i`` (base frame, :func:`retract`) with the prior
  ``N(0, diag(s_t², s_t², s_t², s_r², s_r², s_r²))``: the errors-in-variables form of the maximum-
  likelihood hand-eye with noisy robot poses (Strobl & Hirzinger 2006, "Optimal hand-eye
  calibration", IROS: weight the robot's and the camera's errors by their variances, estimated from
  the data), written on the corners as in Koide & Menegatti 2019, "General hand-eye calibration
  based on reprojection error minimization", RA-L. ``robot_noise="estimate"`` estimates the corner
  noise and ``s_t``, ``s_r`` by variance components (Förstner 1979; Koch, "Parameter estimation and
  hypothesis testing in linear models", 1999): each group's sum of whitened squares over its
  redundancy ``Σ(1 - h_jj)`` (``h``: the hat matrix's diagonal), iterated. The solver is
  Levenberg-Marquardt on the normal equations (12 + intrinsics + 6 per view columns, many rows;
  why not scipy's, in ``_least_squares``); the Jacobian is forward differences, one evaluation per
  global parameter and six for all views' corrections (view ``i``'s corners depend on ``d_i``
  only). Covariance: ``(JᵀJ)⁻¹`` of the whitened problem (the corrections marginalised); robot
  poses exact: ``s² (JᵀJ)⁻¹`` with ``s²`` the residuals' variance per pixel coordinate.
* :func:`robot_aware_covariance`: the covariance of the exact-robot fit when the corners and the
  robot poses have the given noise (sandwich ``A⁻¹ Jᵀ Σ J A⁻¹``).
* :func:`crlb`: the Cramér–Rao bound of the same model (inverse Fisher information at the truth).
* :func:`holdout_rms`: leave-one-view-out. A fitting function gets the other views, returns
  ``(X, Y)``; the left-out view's corners are predicted and compared with the detected ones.
* :func:`world_spread`: each view's own estimate of the board's world pose ``A_i X B_i`` (with its
  PnP pose ``B_i``) and their RMS spread about their mean, in metres and radians.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import pose_delta, retract
from plugins.calibration.boards.detect import Detection
from plugins.calibration.handeye.problem import Setup, chain_poses, model_camera_poses
from plugins.camera.pinhole import CameraModel

F64 = NDArray[np.float64]

__all__ = [
    "ESTIMATE",
    "Refinement",
    "RobotNoise",
    "crlb",
    "holdout_rms",
    "mean_pose",
    "predicted_pixels",
    "refine_reprojection",
    "robot_aware_covariance",
    "view_residuals",
    "world_spread",
]

FitFn = Callable[[NDArray[np.int64]], tuple[F64, F64]]


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


@dataclass(frozen=True)
class RobotNoise:
    """Standard deviations of a robot pose's error: translation (m, per axis) and rotation (rad, per axis),
    isotropic, in the base frame (the perturbation of :func:`engine.transforms.retract`)."""

    trans_m: float
    rot_rad: float

    def sd6(self) -> F64:
        return np.r_[np.full(3, self.trans_m), np.full(3, self.rot_rad)]


ESTIMATE = "estimate"
ROBOT_START = RobotNoise(1e-4, float(np.radians(0.01)))  # 0.1 mm / 0.01 deg: the estimate starts there
ROBOT_FLOOR = RobotNoise(1e-7, 1e-8)  # smallest robot noise kept (the prior's weight stays finite)
VCE_ITERATIONS = 12
VCE_TOL = 0.01  # relative change of every variance component that ends the estimation


@dataclass(frozen=True, eq=False)
class Refinement:
    """The pixel refinement's outcome: ``X``, ``Y``, the camera (refined or as given), covariance of
    ``(dX, dY[, intrinsics])`` (the robot-pose corrections marginalised), per-view RMS / max residual
    (px) through the robot poses as given, the robot noise (``None``: robot poses taken as exact) and
    each view's robot-pose correction ``(n, 6)`` with its whitened square ``robot_d2``."""

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
    robot_noise: RobotNoise | None = None
    robot_deltas: F64 = field(default_factory=lambda: np.zeros((0, 6)))
    robot_d2: F64 = field(default_factory=lambda: np.zeros(0))
    vce_iterations: int = 0


class _Model:
    """The corners' residuals as a function of ``p = (dX, dY, d intrinsics, robot corrections)`` and
    their whitened form and Jacobian (module docstring)."""

    def __init__(
        self, setup: Setup, M: F64, views: Sequence[Detection], camera: CameraModel, X0: F64, Y0: F64,
        n_int: int, robot: bool,
    ) -> None:  # fmt: skip
        self.setup, self.M, self.views, self.camera, self.X0, self.Y0 = setup, M, list(views), camera, X0, Y0
        self.k0 = _intrinsic_vector(camera)
        self.n_int, self.robot = n_int, robot
        self.g = 12 + n_int  # parameters every residual depends on
        self.n = len(self.views)
        self.size = self.g + (6 * self.n if robot else 0)
        bounds = np.cumsum([0] + [2 * v.n for v in self.views])
        self.rows = [slice(int(a), int(b)) for a, b in pairwise(bounds)]
        self.m = int(bounds[-1])
        self._last: tuple[F64, F64] | None = None  # the last point whitened() was asked for, its pixels

    def unpack(self, p: F64) -> tuple[F64, F64, CameraModel, F64]:
        X = retract(self.X0, p[:6])[0]
        Y = retract(self.Y0, p[6:12])[0]
        cam = _with_intrinsics(self.camera, self.k0 + p[12 : self.g]) if self.n_int else self.camera
        d = p[self.g :].reshape(-1, 6) if self.robot else np.zeros((self.n, 6))
        return X, Y, cam, d

    def pixels(self, p: F64) -> F64:
        X, Y, cam, d = self.unpack(p)
        M = retract(self.M, d) if self.robot else self.M
        return np.concatenate([r.ravel() for r in view_residuals(self.setup, M, X, Y, cam, self.views)])

    def whitened(self, p: F64, s_px: float, sd6: F64) -> F64:
        px = self.pixels(p)
        self._last = (p.copy(), px)  # the solver asks for the Jacobian where it last accepted a step
        r = px / s_px
        return np.r_[r, (p[self.g :].reshape(-1, 6) / sd6).ravel()] if self.robot else r

    def jacobian(self, p: F64, s_px: float, sd6: F64, h: float = 1e-7) -> F64:
        """Forward differences: one evaluation per global parameter, six for all views' corrections
        (view ``i``'s corners depend on its own correction only)."""
        last = self._last
        base = last[1] if last is not None and np.array_equal(last[0], p) else self.pixels(p)
        J = np.zeros((self.m + (6 * self.n if self.robot else 0), self.size))
        for j in range(self.g):
            q = p.copy()
            q[j] += h
            J[: self.m, j] = (self.pixels(q) - base) / h
        if self.robot:
            for k in range(6):
                q = p.copy()
                q[self.g + k :: 6] += h
                col = (self.pixels(q) - base) / h
                for i, rows in enumerate(self.rows):
                    J[rows, self.g + 6 * i + k] = col[rows]
            idx = np.arange(6 * self.n)
            J[self.m + idx, self.g + idx] = 1.0 / np.tile(sd6, self.n)
        J[: self.m] /= s_px
        return J


def _leverage(J: F64) -> tuple[F64, F64]:
    """``(JᵀJ)⁺`` and the diagonal of the hat matrix ``J (JᵀJ)⁺ Jᵀ``."""
    Ninv = np.linalg.pinv(J.T @ J)
    return Ninv, np.einsum("ij,ij->i", J @ Ninv, J)


def refine_reprojection(
    setup: Setup,
    T_base_tcp: F64,
    views: Sequence[Detection],
    camera: CameraModel,
    X0: F64,
    Y0: F64,
    *,
    refine_intrinsics: bool = False,
    robot_noise: RobotNoise | Literal["estimate"] | None = None,
    sigma_px: float | None = None,
) -> Refinement:
    """``X``, ``Y`` (and the intrinsics) minimising the corners' pixel residuals (module docstring).

    ``robot_noise``: ``None`` takes the robot poses as exact; a :class:`RobotNoise` adds a correction
    of every robot pose with that prior; ``"estimate"`` also estimates the corner and robot noise
    (variance components). ``sigma_px``: the corner noise when ``robot_noise`` is given (default:
    estimated)."""
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    if len(M) != len(views):
        raise ValueError(f"{len(M)} robot poses for {len(views)} views")
    if refine_intrinsics and camera.model == "fisheye":
        raise ValueError("refining the intrinsics of the fisheye model is not supported; give them fixed")
    n_int = len(_intrinsic_vector(camera)) if refine_intrinsics else 0
    exact = _Model(setup, M, views, camera, X0, Y0, n_int, robot=False)
    sol = _least_squares(exact, np.zeros(exact.size), 1.0, np.ones(6))
    nfev, iterations = int(sol.nfev), 0
    r = sol.fun
    s_px = float(np.sqrt(np.sum(r**2) / max(r.size - exact.size, 1)))
    model, p, noise = exact, sol.x, None
    if robot_noise is not None:
        estimate = isinstance(robot_noise, str)
        if estimate and robot_noise != ESTIMATE:
            raise ValueError(f"robot_noise must be a RobotNoise, 'estimate' or None, got {robot_noise!r}")
        noise = ROBOT_START if estimate else robot_noise
        # the robot's errors explain part of the residuals: start the corner noise at the PnP level
        s_px = float(sigma_px) if sigma_px is not None else 0.5 * s_px
        model = _Model(setup, M, views, camera, X0, Y0, n_int, robot=True)
        p = np.r_[sol.x, np.zeros(6 * len(views))]
        for _ in range(VCE_ITERATIONS if estimate else 1):
            iterations += 1
            sd6 = noise.sd6()
            sol = _least_squares(model, p, s_px, sd6)
            p, nfev = sol.x, nfev + int(sol.nfev)
            if not estimate:
                break  # (a given noise stays as given)
            # Förstner's variance components: each group's sum of squares over its redundancy
            _, lev = _leverage(np.asarray(sol.jac))
            w2 = sol.fun**2
            pix, prior = slice(0, model.m), np.arange(model.m, model.m + 6 * len(views)).reshape(-1, 6)
            t_rows, r_rows = prior[:, :3].ravel(), prior[:, 3:].ravel()
            ratios = [float(np.sum(w2[g]) / max(np.sum(1.0 - lev[g]), 1e-3)) for g in (pix, t_rows, r_rows)]
            s_px = float(s_px * np.sqrt(ratios[0])) if sigma_px is None else s_px
            noise = RobotNoise(
                float(max(noise.trans_m * np.sqrt(ratios[1]), ROBOT_FLOOR.trans_m)),
                float(max(noise.rot_rad * np.sqrt(ratios[2]), ROBOT_FLOOR.rot_rad)),
            )
            if all(abs(x - 1.0) < VCE_TOL for x in ratios[1:] + ratios[: 1 if sigma_px is None else 0]):
                break
    J = np.asarray(sol.jac)
    Ninv = np.linalg.pinv(J.T @ J)  # (the hat matrix's diagonal is for the variance components only)
    if noise is None:  # whitened with sigma 1: the corner noise from the residuals
        Ninv = s_px**2 * Ninv
    cov = Ninv[: model.g, : model.g]
    X, Y, cam, d = model.unpack(p)
    per = view_residuals(setup, M, X, Y, cam, views)
    dist = [np.linalg.norm(v, axis=1) for v in per]
    d2 = np.sum((d / noise.sd6()) ** 2, axis=1) if noise is not None else np.zeros(0)
    return Refinement(
        X, Y, cam, 0.5 * (cov + cov.T), s_px,
        float(np.sqrt(np.mean(np.concatenate(dist) ** 2))),
        np.array([np.sqrt(np.mean(x**2)) for x in dist]), np.array([x.max() for x in dist]),
        nfev, bool(sol.success), bool(n_int), int(exact.m - exact.size), noise,
        d if noise is not None else np.zeros((0, 6)), d2, iterations,
    )  # fmt: skip


@dataclass(frozen=True, eq=False)
class _Solution:
    x: F64
    fun: F64
    jac: F64
    nfev: int
    success: bool


def _least_squares(model: _Model, p0: F64, s_px: float, sd6: F64, max_iter: int = 100) -> _Solution:
    """Levenberg-Marquardt (Marquardt's diagonal scaling) on the normal equations: the Jacobian has
    few columns (12 + intrinsics + 6 per view) and many rows, so ``JᵀJ`` is cheap where a
    factorisation of ``J`` is not. Why not scipy's ``least_squares``, measured: on kuka_2 with the
    robot noise estimated (23016 x 180) ``trf`` (an SVD of J per step) took 6x as long and ``lm``
    (MINPACK's QR) 2.4x; with the variance components ``lm`` ended one trial of
    benchmarks/handeye_images_crlb.py (seed 20261127 + 57) at another minimum (corner noise 0.28 px
    where the truth is 0.1, the hand-eye 1.29 mm off instead of 0.30), which ``trf`` and this solver
    do not; ``trf`` with ``lsmr`` on the sparse Jacobian stopped at a wrong one (the robot noise
    collapsed to its floor)."""
    p = np.asarray(p0, float).copy()
    r = model.whitened(p, s_px, sd6)
    cost, lam, nfev, success = float(r @ r), 1e-4, 1, False
    for _ in range(max_iter):
        J = model.jacobian(p, s_px, sd6)
        A, g = J.T @ J, J.T @ r
        d = np.maximum(np.diag(A), 1e-300)
        while lam < 1e12:
            step = -np.linalg.solve(A + lam * np.diag(d), g)
            r_new = model.whitened(p + step, s_px, sd6)
            nfev += 1
            c_new = float(r_new @ r_new)
            if c_new <= cost:
                break
            lam *= 10.0
        else:
            success = True  # no step lowers the cost: at the minimum to machine precision
            break
        p, r, drop, cost = p + step, r_new, cost - c_new, c_new
        lam = max(lam / 10.0, 1e-12)
        if drop <= 1e-12 * max(cost, 1e-30) or float(step @ (d * step)) <= 1e-20 * max(cost, 1e-30):
            success = True
            break
    return _Solution(p, r, model.jacobian(p, s_px, sd6), nfev, success)


def robot_aware_covariance(
    setup: Setup,
    T_base_tcp: F64,
    views: Sequence[Detection],
    refinement: Refinement,
    sigma_px: float,
    robot_noise: RobotNoise,
) -> F64:
    """Covariance of a refinement that took the robot poses as exact, when the corners have noise
    ``sigma_px`` and the robot poses ``robot_noise``: the sandwich ``A⁻¹ Jᵀ Σ J A⁻¹`` with ``A = JᵀJ``
    and ``Σ = sigma_px² I + J_r Σ_r J_rᵀ`` (``J_r``: the corners' Jacobian in the robot-pose
    corrections, block diagonal over the views)."""
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    cam0 = refinement.camera
    n_int = len(_intrinsic_vector(cam0)) if refinement.intrinsics_refined else 0
    model = _Model(setup, M, views, cam0, refinement.X, refinement.Y, n_int, robot=True)
    J = model.jacobian(np.zeros(model.size), 1.0, np.ones(6))[: model.m]
    Jg, Jr = J[:, : model.g], J[:, model.g :]
    Ainv = np.linalg.pinv(Jg.T @ Jg)
    K = Jg.T @ Jr
    meat = sigma_px**2 * (Jg.T @ Jg) + (K * np.tile(robot_noise.sd6() ** 2, len(views))) @ K.T
    cov = Ainv @ meat @ Ainv
    return 0.5 * (cov + cov.T)


def crlb(
    setup: Setup,
    T_base_tcp: F64,
    views: Sequence[Detection],
    camera: CameraModel,
    X: F64,
    Y: F64,
    sigma_px: float,
    *,
    robot_noise: RobotNoise | None = None,
    refine_intrinsics: bool = False,
) -> F64:
    """Cramér–Rao bound of ``(dX, dY[, intrinsics])`` at the true ``X``, ``Y``: the inverse Fisher
    information of the refinement's model (independent ``N(0, sigma_px²)`` corner noise; with
    ``robot_noise``, the true robot poses as nuisance parameters observed through the given ones).
    The views give the board points seen; their detected pixels do not enter."""
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    n_int = len(_intrinsic_vector(camera)) if refine_intrinsics else 0
    model = _Model(setup, M, views, camera, X, Y, n_int, robot=robot_noise is not None)
    sd6 = robot_noise.sd6() if robot_noise is not None else np.ones(6)
    J = model.jacobian(np.zeros(model.size), float(sigma_px), sd6)
    info = J.T @ J
    return np.linalg.inv(info)[: model.g, : model.g]


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
