"""Signatures of the geometric effects (DH errors, tool/base offsets) and of thermal drift."""

from __future__ import annotations

import numpy as np
import pytest

from engine.transforms import inv, log_se3
from plugins.robot.effects import (
    BaseFrameError,
    GeometricErrors,
    JointOffset,
    LinkLength,
    SampleContext,
    ThermalDrift,
    ToolOffsetError,
)
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects

UR5E = load_robot_model("ur5e")
Q = np.random.default_rng(0).uniform(-np.pi, np.pi, size=(100, 6))


def _dh_errors(scale: float, seed: int = 1) -> GeometricErrors:
    rng = np.random.default_rng(seed)
    names = [n for n in UR5E.param_names if n.startswith("joint")]
    return GeometricErrors(tuple(names), tuple(scale * rng.normal(size=len(names))))


def test_dh_errors_match_the_first_order_jacobian_prediction():
    """Pose error (space twist) = J_params @ offsets up to second order: < 1 % for 0.1 mm / 0.1 mrad."""
    effect = _dh_errors(1e-4)
    robot = RobotWithEffects(UR5E, [effect])
    T_true, T_nom = robot.fk(Q), UR5E.fk(Q)
    actual = np.stack([log_se3(a @ inv(b)) for a, b in zip(T_true, T_nom, strict=True)])
    dv = effect.param_offsets(UR5E, Q, SampleContext())
    _, J = UR5E.param_jacobian(Q, frame="space")
    predicted = J @ dv
    rel = np.linalg.norm(actual - predicted, axis=1) / np.linalg.norm(actual, axis=1)
    assert rel.max() < 0.01
    # and the position error is of the size of the parameter errors (sub-mm)
    err_mm = np.linalg.norm(T_true[:, :3, 3] - T_nom[:, :3, 3], axis=1) * 1e3
    assert 0.05 < np.median(err_mm) < 2.0


def test_dh_errors_scale_linearly():
    small = RobotWithEffects(UR5E, [_dh_errors(5e-5)]).fk(Q)[:, :3, 3]
    large = RobotWithEffects(UR5E, [_dh_errors(1e-4)]).fk(Q)[:, :3, 3]
    p0 = UR5E.fk(Q)[:, :3, 3]
    ratio = np.linalg.norm(large - p0, axis=1) / np.linalg.norm(small - p0, axis=1)
    assert np.allclose(ratio, 2.0, rtol=0.01)


def test_joint_offset_and_link_length_act_on_the_named_parameters():
    q = Q[:5]
    a = RobotWithEffects(UR5E, [JointOffset((3,), (1e-3,))]).fk(q)
    b = UR5E.fk(q + np.array([0, 0, 1e-3, 0, 0, 0]))  # a zero offset is a joint angle shift
    assert np.allclose(a, b, atol=1e-15)
    c = RobotWithEffects(UR5E, [LinkLength((2, 4), (1e-3, -2e-3))]).fk(q)  # auto: a2 and d4
    assert np.allclose(c, UR5E.with_param_offsets({"joint2.a": 1e-3, "joint4.d": -2e-3}).fk(q), atol=1e-15)


def test_tool_offset_moves_the_tcp_in_the_flange_frame():
    dp = np.array([2e-4, -1e-4, 5e-4])
    robot = RobotWithEffects(UR5E, [ToolOffsetError(("tx", "ty", "tz"), tuple(dp))])
    T_true, T_nom = robot.fk(Q), UR5E.fk(Q)
    assert np.allclose(T_true[:, :3, 3] - T_nom[:, :3, 3], T_nom[:, :3, :3] @ dp, atol=1e-15)
    rot = RobotWithEffects(UR5E, [ToolOffsetError(("rx", "rz"), (1e-3, -2e-3))]).fk(Q)
    assert np.allclose(rot[:, :3, 3], T_nom[:, :3, 3], atol=1e-15)  # TCP rotation leaves the TCP point
    assert not np.allclose(rot[:, :3, :3], T_nom[:, :3, :3], atol=1e-6)


def test_base_frame_error_shifts_every_pose_rigidly():
    robot = RobotWithEffects(UR5E, [BaseFrameError(("tz",), (3e-4,))])
    d = robot.fk(Q)[:, :3, 3] - UR5E.fk(Q)[:, :3, 3]
    assert np.allclose(d, (0, 0, 3e-4), atol=1e-15)


def test_thermal_drift_grows_with_time_then_saturates():
    tau = 1200.0
    effect = ThermalDrift.linear_expansion(UR5E, 8.0, time_constant_s=tau, base_height_growth_m=5e-5)
    robot = RobotWithEffects(UR5E, [effect])
    q = np.tile(UR5E.home, (8, 1))
    t = np.array([0.0, 0.1, 0.5, 1.0, 2.0, 4.0, 10.0, 20.0]) * tau
    drift = np.linalg.norm(robot.fk(q, SampleContext(t_s=t))[:, :3, 3] - UR5E.fk(q)[:, :3, 3], axis=1)
    assert drift[0] == 0.0
    assert np.all(np.diff(drift) > 0)  # grows monotonically
    saturated = drift[-1]
    assert 1e-5 < saturated < 1e-3  # tens of micrometres for 8 K on aluminium links
    assert abs(drift[3] / saturated - (1 - np.exp(-1))) < 1e-3  # first-order: 63 % at t = tau
    assert abs(drift[-2] / saturated - 1) < 1e-4  # saturated after 10 tau
    # offsets follow the nominal lengths: a2 (negative) grows more negative
    a2 = effect.saturation_offsets[effect.names.index("joint2.a")]
    assert a2 < 0 and np.isclose(a2, -0.425 * 23e-6 * 8.0)


def test_thermal_drift_needs_time():
    robot = RobotWithEffects(UR5E, [ThermalDrift(("joint2.a",), (1e-4,))])
    with pytest.raises(ValueError, match="t_s"):
        robot.fk(Q[:1])
