"""The kinematic calibration problem: its options (:class:`KinematicCalibrationConfig`), the
parameters a model and a kind of data can identify (:func:`candidate_parameters`), the whitened
residuals and Jacobian around the current model (:class:`ResidualProblem`), and the held-out RMS a correct
model is expected to reach (:func:`expected_holdout_rms`). Solved by
plugins.calibration.kinematics.calibrate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import so3_left_jacobian_inv
from plugins.calibration.kinematics.data import KinematicSamples
from plugins.calibration.kinematics.points import ToolPoints, split_names
from plugins.robot.kinematics import RobotModel

F64 = NDArray[np.float64]

_JOINT_PARAMS = {
    "dh": ("theta", "d", "a", "alpha", "beta"),
    "mdh": ("alpha", "a", "beta", "theta", "d"),
    "poe": ("tx", "ty", "tz", "rx", "ry", "theta"),
}


@dataclass
class KinematicCalibrationConfig:
    """Options of :func:`calibrate_kinematics` (SI units)."""

    parameterisation: Literal["dh", "mdh", "poe"] | None = None  # default: the model's convention
    estimate_base: bool = True  # unknown measurement frame (T_meas_base)
    estimate_tool: bool = True  # unknown tool point (and orientation with full-pose data)
    noise_position_m: float = 5e-5  # per axis, one sigma
    noise_rotation_rad: float = 1e-4
    trust_noise: bool = False  # covariance from the given noise instead of the residual variance
    identifiability_tol: float = 1e-6
    max_iterations: int = 30
    plausible_offset_m: float = 0.01  # joint parameters moving further than this are reported
    plausible_offset_rad: float = np.radians(2.0)
    max_step_m: float = 0.05  # LM step limit: change of the predictions per iteration
    holdout_fraction: float = 0.25  # used when no held-out samples are given
    rng_seed: int = 0
    structural_poses: int = 300


class ResidualProblem:
    """Residuals and Jacobian of the kept parameters around ``model``'s current values.

    ``names`` may hold point parameters (``tool[k].t*``, several measured points: :mod:`.points`):
    ``x`` then moves ``points``' offsets too, and every row is evaluated at its own point.
    """

    def __init__(
        self, model: RobotModel, samples: KinematicSamples, names: list[str], cfg, points: ToolPoints | None = None
    ) -> None:
        self.model = model
        self.samples = samples
        self.names = names
        self.chain_pos, self.point_pos = split_names(names)
        self.idx = [model.chain.index(names[i]) for i in self.chain_pos]
        self.v0 = model.param_values.copy()
        self.points = points
        self.sp = cfg.noise_position_m
        self.sr = cfg.noise_rotation_rad

    def values(self, x: F64) -> F64:
        """The chain's values (``(P,)``: the model's own, the first point's tool) at ``x``."""
        v = self.v0.copy()
        v[self.idx] += np.asarray(x)[self.chain_pos]
        return v

    def points_at(self, x: F64) -> ToolPoints | None:
        """The measured points' offsets at ``x``."""
        if self.points is None or not self.point_pos:
            return self.points
        return self.points.with_offsets(self.points.flat() + np.asarray(x)[self.point_pos])

    def sample_values(self, x: F64) -> F64:
        """The values each sample is evaluated at (``(N, P)`` with several points)."""
        pts = self.points_at(x)
        return self.values(x) if pts is None else pts.values(self.model, self.values(x), self.samples)

    def residuals(self, x: F64) -> tuple[F64, F64]:
        """Unwhitened residuals (N, 3) positions [m] and (N, 3) rotation vectors [rad] (or None)."""
        T = self.model.fk(self.samples.q, self.sample_values(x))
        rp = self.samples.positions - T[:, :3, 3]
        if not self.samples.full_pose:
            return rp, None
        rr = Rotation.from_matrix(self.samples.rotations @ np.swapaxes(T[:, :3, :3], 1, 2)).as_rotvec()
        return rp, rr

    def __call__(self, x: F64) -> tuple[F64, F64]:
        """Whitened residual vector and its Jacobian w.r.t. x."""
        T, Jall = self.model.param_jacobian(self.samples.q, self.sample_values(x), frame="base")
        J = np.zeros((Jall.shape[0], 6, len(self.names)))
        J[:, :, self.chain_pos] = Jall[:, :, self.idx]
        pts = self.points_at(x)
        if self.point_pos and pts is not None:
            J[:, :, self.point_pos] = pts.columns(Jall, self.model, self.samples)
        rp = (self.samples.positions - T[:, :3, 3]) / self.sp
        Jp = -J[:, :3] / self.sp
        if not self.samples.full_pose:
            return rp.ravel(), Jp.reshape(-1, len(self.names))
        phi = Rotation.from_matrix(self.samples.rotations @ np.swapaxes(T[:, :3, :3], 1, 2)).as_rotvec()
        Jr = np.stack([-so3_left_jacobian_inv(-p) @ Jw for p, Jw in zip(phi, J[:, 3:], strict=True)])
        r = np.concatenate([rp, phi / self.sr], axis=1).ravel()
        Jall = np.concatenate([Jp, Jr / self.sr], axis=1).reshape(-1, len(self.names))
        return r, Jall


def candidate_parameters(model: RobotModel, full_pose: bool, cfg: KinematicCalibrationConfig) -> list[str]:
    """Parameters to estimate, in identifiability priority order: base, tool, joints outwards.

    The measurement frame and the tool come first, so that joint parameters equivalent to them (joint
    1's zero and height, the last joint's offsets) are the ones fixed at their nominal values: the
    estimated joint parameters then mean the same thing whatever the data's frames were.
    """
    names: list[str] = []
    if cfg.estimate_base:
        names += [f"base.{k}" for k in ("tx", "ty", "tz", "rx", "ry", "rz")]
    if cfg.estimate_tool:
        tool = ("tx", "ty", "tz", "rx", "ry", "rz") if full_pose else ("tx", "ty", "tz")
        names += [f"tool.{k}" for k in tool]
    for j in range(1, model.dof + 1):
        names += [f"joint{j}.{k}" for k in _JOINT_PARAMS[model.convention]]
    return names


def random_configs(model: RobotModel, n: int, seed: int) -> F64:
    lo, hi = np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi)
    return lo + np.random.default_rng(seed).random((n, model.dof)) * (hi - lo)


def expected_holdout_rms(
    model: RobotModel,
    holdout: KinematicSamples,
    names: list[str],
    cov: F64,
    sigma_m: float,
    points: ToolPoints | None = None,
) -> tuple[float, float]:
    """Expected 3-D position RMS on held-out poses for a correct model, and its degrees of freedom.

    A held-out error is the new measurement's noise minus the calibrated model's prediction error,
    ``e_i = n_i - A_i d`` (``A_i`` the position Jacobian of the identified parameters, ``d`` their
    error, covariance ``cov``), so ``E|e_i|^2 = 3 sigma^2 + tr(A_i cov A_i^T)``: the noise floor
    raised by what the fit left uncertain. Averaged over poses like the calibration ones this is
    ``3 sigma^2 (1 + p / n)`` for ``p`` parameters and ``n`` residuals; here it is computed exactly
    for the given poses. Returns ``(sqrt(mean E|e_i|^2), dof)`` with ``dof`` Satterthwaite's degrees
    of freedom of the held-out mean square, ``(tr S)^2 / tr(S^2)`` for ``S = sigma^2 I + A cov A^T``:
    ``(RMS / expected)^2`` then follows ``chi2(dof) / dof`` (``F(dof, nu)`` when ``sigma`` and ``cov``
    rest on a variance estimated with ``nu`` degrees of freedom).
    """
    cfg = KinematicCalibrationConfig(noise_position_m=1.0)
    _, J = ResidualProblem(model, holdout, names, cfg, points)(np.zeros(len(names)))
    A = -J.reshape(holdout.n_samples, -1, len(names))[:, :3, :].reshape(-1, len(names))
    m = A.shape[0]
    M = cov @ (A.T @ A)  # tr(A cov A^T) = tr(M), tr((A cov A^T)^2) = tr(M^2)
    tr_s = m * sigma_m**2 + float(np.trace(M))
    tr_s2 = m * sigma_m**4 + 2.0 * sigma_m**2 * float(np.trace(M)) + float(np.sum(M * M.T))
    return float(np.sqrt(tr_s / holdout.n_samples)), tr_s**2 / tr_s2


def error_rows(model: RobotModel, samples: KinematicSamples, points: ToolPoints | None = None) -> dict[str, float]:
    T = model.fk(samples.q, None if points is None else points.values(model, None, samples))
    e = (samples.positions - T[:, :3, 3]) * 1e3
    row = {
        "rms_mm": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
        "max_mm": float(np.linalg.norm(e, axis=1).max()),
        "rms_x_mm": float(np.sqrt(np.mean(e[:, 0] ** 2))),
        "rms_y_mm": float(np.sqrt(np.mean(e[:, 1] ** 2))),
        "rms_z_mm": float(np.sqrt(np.mean(e[:, 2] ** 2))),
    }
    if samples.full_pose:
        rr = Rotation.from_matrix(samples.rotations @ np.swapaxes(T[:, :3, :3], 1, 2)).magnitude()
        row["rms_rot_deg"] = float(np.degrees(np.sqrt(np.mean(rr**2))))
    return row
