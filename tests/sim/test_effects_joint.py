"""Signatures of the joint-space effects: compliance, backlash, encoder eccentricity."""

from __future__ import annotations

import numpy as np
import pytest

from plugins.robot.effects import Backlash, EncoderEccentricity, JointCompliance, SampleContext
from plugins.robot.model_file import load_robot_model, robot_model_from_dict
from plugins.robot.with_effects import RobotWithEffects

UR5E = load_robot_model("ur5e")

# A planar two-link arm whose joints are horizontal (base turned 90 deg about x) and whose link
# masses sit on the link lines: gravity torque is exactly zero when the arm points straight up.
PLANAR = robot_model_from_dict(
    {
        "name": "planar",
        "convention": "dh",
        "base": {"rpy": ["pi/2", 0, 0]},
        "joints": [
            {"a": 0.4, "alpha": 0, "d": 0, "lower": "-pi", "upper": "pi", "max_speed": 1, "max_accel": 1},
            {"a": 0.3, "alpha": 0, "d": 0, "lower": "-pi", "upper": "pi", "max_speed": 1, "max_accel": 1},
        ],
        "links": [{"mass": 5.0, "com_link": [-0.2, 0, 0]}, {"mass": 3.0, "com_link": [-0.15, 0, 0]}],
    }
)


def test_compliance_deflection_is_proportional_to_gravity_torque():
    c = (2e-6, 3e-6)
    robot = RobotWithEffects(UR5E, [JointCompliance((2, 3), c)])
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, size=(200, 6))
    dq = robot.actual_joints(q) - q
    tau = UR5E.gravity_torque(q)
    assert np.allclose(dq[:, [1, 2]], tau[:, [1, 2]] * np.array(c), rtol=0, atol=1e-15)
    assert np.all(dq[:, [0, 3, 4, 5]] == 0)
    assert tau[:, 1].std() > 10.0  # the sample spans a wide range of torques


def test_compliance_is_zero_with_the_arm_vertical_and_largest_horizontal():
    robot = RobotWithEffects(PLANAR, [JointCompliance((1, 2), (1e-5, 1e-5))])
    elevation = np.linspace(0.0, np.pi / 2, 10)  # 0 = horizontal, pi/2 = straight up
    q = np.column_stack([elevation, np.zeros_like(elevation)])
    dq = robot.actual_joints(q) - q
    # tau_1 = -g (m1 l1/2 + m2 (l1 + l2/2)) cos(elevation): deflection follows cos, zero when vertical
    g = 9.80665
    expected = -1e-5 * g * (5.0 * 0.2 + 3.0 * (0.4 + 0.15)) * np.cos(elevation)
    assert np.allclose(dq[:, 0], expected, atol=1e-15)
    assert abs(dq[-1, 0]) < 1e-15 and abs(dq[-1, 1]) < 1e-15
    assert np.all(np.diff(np.abs(dq[:, 0])) < 0)  # shrinks monotonically towards vertical


def test_compliance_on_ur5e_shoulder_follows_the_arm_elevation():
    """UR5e with the arm straight: shoulder deflection ~ cos(elevation), ~0 when the arm is upright."""
    robot = RobotWithEffects(UR5E, [JointCompliance((2,), (3e-6,))])
    q2 = np.linspace(-np.pi / 2, 0.0, 7)  # -pi/2 = upright, 0 = horizontal
    q = np.column_stack([np.zeros(7), q2, np.zeros(7), -np.pi / 2 * np.ones(7), np.zeros(7), np.zeros(7)])
    dq2 = (robot.actual_joints(q) - q)[:, 1]
    assert abs(dq2[0]) < 0.01 * abs(dq2[-1])  # wrist COM offsets leave < 1 % when upright
    assert np.all(np.diff(np.abs(dq2)) > 0)


def test_compliance_grows_with_payload():
    robot = RobotWithEffects(UR5E, [JointCompliance((2,), (3e-6,))])
    q = np.tile(UR5E.home, (3, 1))
    dq = robot.actual_joints(q, SampleContext(payload_kg=np.array([0.0, 2.5, 5.0]))) - q
    steps = np.diff(dq[:, 1])
    assert abs(steps[0] - steps[1]) < 1e-15 and abs(steps[0]) > 0  # linear in the payload ...
    assert np.all(np.diff(np.abs(dq[:, 1])) > 0)  # ... and growing with it


def test_backlash_flips_sign_with_approach_direction():
    b = np.array([4e-4, 2e-4, 1e-4])
    robot = RobotWithEffects(UR5E, [Backlash((1, 2, 3), tuple(b))])
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, size=(20, 6))
    up = SampleContext(direction=np.ones(6))
    down = SampleContext(direction=-np.ones(6))
    dq_up = robot.actual_joints(q, up) - q
    dq_down = robot.actual_joints(q, down) - q
    assert np.allclose(dq_up[:, :3], -b / 2, atol=1e-16) and np.allclose(dq_down[:, :3], b / 2, atol=1e-16)
    assert np.allclose(dq_up[:, :3] - dq_down[:, :3], -b, atol=1e-16)
    # at the TCP: equal and opposite displacements (to first order), millimetre-scale apart
    p0 = UR5E.fk(q)[:, :3, 3]
    e_up, e_down = robot.fk(q, up)[:, :3, 3] - p0, robot.fk(q, down)[:, :3, 3] - p0
    assert np.all(np.linalg.norm(e_up + e_down, axis=1) < 1e-3 * np.linalg.norm(e_up - e_down, axis=1))
    assert np.median(np.linalg.norm(e_up - e_down, axis=1)) > 1e-4


def test_backlash_per_joint_direction_and_missing_context():
    robot = RobotWithEffects(UR5E, [Backlash((2,), (1e-3,))])
    q = np.zeros((2, 6))
    d = np.ones((2, 6))
    d[1, 1] = -1
    dq = robot.actual_joints(q, SampleContext(direction=d)) - q
    assert dq[0, 1] == -5e-4 and dq[1, 1] == 5e-4
    with pytest.raises(ValueError, match="direction"):
        robot.fk(q)
    with pytest.raises(ValueError, match=r"\+1 or -1"):
        robot.fk(q, SampleContext(direction=np.zeros((2, 6))))


def test_eccentricity_is_sinusoidal_in_the_joint_angle():
    a, b = 8e-5, -3e-5
    robot = RobotWithEffects(UR5E, [EncoderEccentricity((4,), (a,), (b,))])
    rng = np.random.default_rng(2)
    q = rng.uniform(-np.pi, np.pi, size=(100, 6))
    q[:, 3] = np.linspace(-2 * np.pi, 2 * np.pi, 100)
    err = (robot.actual_joints(q) - q)[:, 3]
    # recover the amplitudes by a linear fit on sin/cos of the joint angle: exact sinusoid
    A = np.column_stack([np.sin(q[:, 3]), np.cos(q[:, 3])])
    coef, *_ = np.linalg.lstsq(A, err, rcond=None)
    assert np.allclose(coef, (a, b), atol=1e-14)
    assert np.abs(A @ coef - err).max() < 1e-14
    # periodic in q4, independent of the other joints
    q2 = q.copy()
    q2[:, 3] += 2 * np.pi
    q2[:, [0, 1, 2]] = rng.uniform(-np.pi, np.pi, size=(100, 3))
    assert np.allclose((robot.actual_joints(q2) - q2)[:, 3], err, atol=1e-14)
    assert np.all((robot.actual_joints(q) - q)[:, [0, 1, 2, 4, 5]] == 0)
    assert np.isclose(np.abs(err).max(), np.hypot(a, b), rtol=1e-3)


def test_effects_are_off_by_default():
    q = np.random.default_rng(3).uniform(-3, 3, size=(5, 6))
    ctx = SampleContext(direction=np.ones(6))
    robot = RobotWithEffects(UR5E, [JointCompliance(), Backlash(), EncoderEccentricity()])
    assert np.array_equal(robot.fk(q, ctx), UR5E.fk(q))
    robot = RobotWithEffects(UR5E, [JointCompliance((2,), (0.0,)), Backlash((1,), (0.0,))])
    assert np.array_equal(robot.fk(q, ctx), UR5E.fk(q))
