"""Simulated kinematic-calibration data sets (helper for the tests; not a test module)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, exp_se3
from plugins.calibration.kinematics import KinematicSamples
from plugins.robot.effects import GeometricErrors
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects

NOISE_M = 5e-5  # 0.05 mm per axis, the laser-tracker-like noise
T_MEAS_WORLD = exp_se3([1.5, 0.3, 0.2, 0.1, -0.05, 2.0])  # tracker frame far from the robot
TOOL_TRUE = T_from_Rt(Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix(), (0.03, -0.02, 0.12))
TOOL_NOMINAL = T_from_Rt(np.eye(3), (0.0, 0.0, 0.1))  # what the user thinks (off by ~4 cm)


def dh_errors(model, seed: int, length_m: float = 2e-4, angle_rad: float = 2e-4) -> GeometricErrors:
    """Random errors on every DH parameter of every joint (theta, d, a, alpha, beta)."""
    rng = np.random.default_rng(seed)
    names = [n for n in model.param_names if n.startswith("joint")]
    vals = [(length_m if model.chain.param_kind(n) == "length" else angle_rad) * rng.normal() for n in names]
    return GeometricErrors(tuple(names), tuple(vals))


def true_robot(name: str = "ur5e", seed: int = 1, **kw) -> RobotWithEffects:
    nominal = load_robot_model(name)
    return RobotWithEffects(nominal.with_base(T_MEAS_WORLD).with_tool(TOOL_TRUE), [dh_errors(nominal, seed, **kw)])


def random_poses(model, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi)
    return lo + rng.random((n, model.dof)) * (hi - lo)


def measure(
    robot: RobotWithEffects,
    q: np.ndarray,
    seed: int,
    noise_m: float = NOISE_M,
    rot_noise_rad: float | None = None,
) -> KinematicSamples:
    """Tool-point positions (and orientations when rot_noise_rad is given) with Gaussian noise."""
    rng = np.random.default_rng(seed)
    T = robot.fk(q)
    p = T[:, :3, 3] + rng.normal(0.0, noise_m, size=(len(q), 3))
    R = None
    if rot_noise_rad is not None:
        R = (
            Rotation.from_rotvec(rng.normal(0, rot_noise_rad, (len(q), 3))) * Rotation.from_matrix(T[:, :3, :3])
        ).as_matrix()
    return KinematicSamples(q, p, R)


def nominal_model(name: str = "ur5e"):
    return load_robot_model(name).with_tool(TOOL_NOMINAL)
