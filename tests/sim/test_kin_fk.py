"""Forward kinematics against known poses, and DH / MDH / POE representations of the same robot.

Known poses are derived by hand from the published geometry (not copied from our FK):

UR5e (Universal Robots' DH table: d1 = 0.1625, a2 = -0.425, a3 = -0.3922, d4 = 0.1333, d5 = 0.0997,
d6 = 0.0996, alpha = (pi/2, 0, 0, pi/2, -pi/2, 0)). Axis directions at q = 0 follow from the alphas:
joint 1 along +z; joints 2, 3, 4 along -y; joint 5 along -z; joint 6 along -y.

* q = 0: both arm links lie along -x at shoulder height d1, wrist 1 steps d4 along -y, wrist 2 steps
  d5 down, wrist 3 steps d6 along -y: p = (a2 + a3, -(d4 + d6), d1 - d5) = (-0.8172, -0.2329, 0.0628).
  The flange frame is DH frame 6 with R = Rx(a1) Rx(a4) Rx(a5) = Rx(pi/2) (all alpha rotations
  are about the same x axis when the thetas are 0). Public UR5e tests quote the same numbers.
* q = (0, -pi/2, 0, -pi/2, 0, 0) ("upright"): -pi/2 about -y turns the arm from -x to +z, so the
  links stack up: z = d1 + |a2| + |a3| = 0.9797 at wrist 1; the joint-2..4 rotations total -pi about
  -y, which turns wrist 2's "down" step into "up": z = 0.9797 + d5 = 1.0794; y = -(d4 + d6).
  R = Ry(pi) Rx(pi/2).
* q = (0, -pi/2, pi/2, -pi/2, -pi/2, 0) (UR's usual home): upper arm up (elbow at z = d1 + 0.425),
  forearm back along -x (x = -0.3922), wrist 1 steps -y by d4, joints 2..4 total -pi/2 about -y so
  wrist 2 steps d5 along -x (x = -0.4919), wrist 2 at -pi/2 points the flange down: z = 0.5875 - d6
  = 0.4879, y = -0.1333. R = Rx(pi/2) Ry(pi/2) Rx(pi/2).

ABB IRB 120 (product specification dimensions 290 / 270 / 70 / 302 / 72 mm; ABB's axis senses):
at q = 0 the flange (tool0) is at (374, 0, 630) mm with its z along +x, i.e. ABB quaternion
(w, x, y, z) = (0.7071, 0, 0.7071, 0); with axis 5 at +90 deg the flange points down at (302, 0, 558) mm.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from engine.transforms import exp_se3, inv, pose_error
from plugins.robot.model_file import load_robot_model, robot_model_from_dict
from plugins.vendor_poses import abb_from_T

Rx = lambda a: Rotation.from_euler("x", a).as_matrix()  # noqa: E731
Ry = lambda a: Rotation.from_euler("y", a).as_matrix()  # noqa: E731
PI = np.pi


@pytest.fixture(scope="module")
def ur5e():
    return load_robot_model("ur5e")


@pytest.fixture(scope="module")
def irb120():
    return load_robot_model("abb_irb120")


@pytest.mark.parametrize(
    ("q", "p", "R"),
    [
        ((0, 0, 0, 0, 0, 0), (-0.8172, -0.2329, 0.0628), Rx(PI / 2)),
        ((0, -PI / 2, 0, -PI / 2, 0, 0), (0.0, -0.2329, 1.0794), Ry(PI) @ Rx(PI / 2)),
        (
            (0, -PI / 2, PI / 2, -PI / 2, -PI / 2, 0),
            (-0.4919, -0.1333, 0.4879),
            Rx(PI / 2) @ Ry(PI / 2) @ Rx(PI / 2),
        ),
    ],
    ids=["zero", "upright", "home"],
)
def test_ur5e_known_poses(ur5e, q, p, R):
    T = ur5e.fk(np.array(q, dtype=float))
    assert np.allclose(T[:3, 3], p, atol=1e-12)
    assert np.allclose(T[:3, :3], R, atol=1e-12)


def test_ur5e_base_rotation_turns_the_whole_arm(ur5e):
    """theta1 = +90 deg rotates the zero pose about +z: (x, y) -> (-y, x)."""
    T = ur5e.fk(np.array([PI / 2, 0, 0, 0, 0, 0]))
    assert np.allclose(T[:3, 3], (0.2329, -0.8172, 0.0628), atol=1e-12)


def test_irb120_known_poses(irb120):
    pos_mm, quat_wxyz = abb_from_T(irb120.fk(np.zeros(6)))
    assert np.allclose(pos_mm, (374.0, 0.0, 630.0), atol=1e-9)
    assert np.allclose(quat_wxyz, (np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0), atol=1e-12)
    T = irb120.fk(np.radians([0, 0, 0, 0, 90, 0]))
    assert np.allclose(T[:3, 3], (0.302, 0.0, 0.558), atol=1e-12)
    assert np.allclose(T[:3, 2], (0.0, 0.0, -1.0), atol=1e-12)
    # positive axis 2 tilts the arm forward (+x) and down, positive axis 3 tilts the forearm down
    p0 = irb120.fk(np.zeros(6))[:3, 3]
    p2 = irb120.fk(np.radians([0, 10, 0, 0, 0, 0]))[:3, 3]
    p3 = irb120.fk(np.radians([0, 0, 10, 0, 0, 0]))[:3, 3]
    assert p2[0] > p0[0] and p2[2] < p0[2]
    assert p3[2] < p0[2]


# --------------------------------------------------------------------------- same robot, three forms

UR5E_MDH = {  # Craig's convention, written by hand from UR's DH table (alpha_{i-1}, a_{i-1}, d_i)
    "name": "ur5e_mdh",
    "convention": "mdh",
    "joints": [
        {"alpha": 0.0, "a": 0.0, "d": 0.1625},
        {"alpha": "pi/2", "a": 0.0, "d": 0.0},
        {"alpha": 0.0, "a": -0.425, "d": 0.0},
        {"alpha": 0.0, "a": -0.3922, "d": 0.1333},
        {"alpha": "pi/2", "a": 0.0, "d": 0.0997},
        {"alpha": "-pi/2", "a": 0.0, "d": 0.0996},
    ],
}

# Modern Robotics (Lynch & Park, Example 4.5) UR5 screw axes in its own base frame, with UR5e sizes
L1, L2, W1, W2, H1, H2 = 0.425, 0.3922, 0.1333, 0.0996, 0.1625, 0.0997
UR5E_POE_MR = {
    "name": "ur5e_poe",
    "convention": "poe",
    "base": {"rpy": [0, 0, "pi"]},  # MR's base frame is UR's turned by 180 deg about z
    "joints": [
        {"axis": [0, 0, 1], "point": [0, 0, 0]},
        {"axis": [0, 1, 0], "point": [0, 0, H1]},
        {"axis": [0, 1, 0], "point": [L1, 0, H1]},
        {"axis": [0, 1, 0], "point": [L1 + L2, 0, H1]},
        {"axis": [0, 0, -1], "point": [L1 + L2, W1, 0]},
        {"axis": [0, 1, 0], "point": [L1 + L2, 0, H1 - H2]},
    ],
    "flange_at_zero": {"matrix": [[-1, 0, 0, L1 + L2], [0, 0, 1, W1 + W2], [0, 1, 0, H1 - H2], [0, 0, 0, 1]]},
}

# ABB IRB 120 from ROS-Industrial's URDF (joint axes and origins at q = 0, tool0 = Ry(90 deg))
IRB120_POE = {
    "name": "irb120_poe",
    "convention": "poe",
    "joints": [
        {"axis": [0, 0, 1], "point": [0, 0, 0]},
        {"axis": [0, 1, 0], "point": [0, 0, 0.29]},
        {"axis": [0, 1, 0], "point": [0, 0, 0.56]},
        {"axis": [1, 0, 0], "point": [0, 0, 0.63]},
        {"axis": [0, 1, 0], "point": [0.302, 0, 0.63]},
        {"axis": [1, 0, 0], "point": [0.374, 0, 0.63]},
    ],
    "flange_at_zero": {"xyz": [0.374, 0, 0.63], "rpy": [0, "pi/2", 0]},
}


def _with_limits(d: dict) -> dict:
    d = dict(d)
    d["joints"] = [dict(j, lower=-7, upper=7, max_speed=3, max_accel=10) for j in d["joints"]]
    return d


def _random_q(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-PI, PI, size=(n, 6))


@pytest.mark.parametrize("other", [UR5E_MDH, UR5E_POE_MR], ids=["mdh_by_hand", "poe_modern_robotics"])
def test_ur5e_dh_mdh_poe_agree(ur5e, other):
    model = robot_model_from_dict(_with_limits(other))
    q = _random_q(500, 1)
    assert np.abs(ur5e.fk(q) - model.fk(q)).max() < 1e-12


def test_irb120_dh_matches_the_urdf_screws(irb120):
    model = robot_model_from_dict(_with_limits(IRB120_POE))
    q = _random_q(500, 2)
    assert np.abs(irb120.fk(q) - model.fk(q)).max() < 1e-12


@pytest.mark.parametrize("name", ["ur5e", "abb_irb120"])
def test_conversions_preserve_fk_jacobian_and_gravity(name):
    """dh -> mdh -> dh and dh -> poe with a tool, a base and non-zero geometric errors."""
    rng = np.random.default_rng(3)
    m = load_robot_model(name).with_tool(exp_se3([0.01, -0.02, 0.12, 0.1, 0.2, -0.3]))
    m = m.with_base(exp_se3([0.3, 0.1, 0.2, 0.05, -0.02, 0.4]))
    names = [n for n in m.param_names if n.startswith("joint") or n.startswith("tool")]
    m = m.with_param_offsets({n: 1e-3 * rng.normal() for n in names})
    q = _random_q(200, 4)
    for conv in ("mdh", "poe"):
        other = m.to_convention(conv)
        assert other.convention == conv
        assert np.abs(m.fk(q) - other.fk(q)).max() < 1e-12
        assert np.abs(m.jacobian(q) - other.jacobian(q)).max() < 1e-12
        assert np.abs(m.gravity_torque(q) - other.gravity_torque(q)).max() < 1e-9
    back = m.to_convention("mdh").to_convention("dh")
    assert np.abs(m.fk(q) - back.fk(q)).max() < 1e-12


def test_vectorised_fk_equals_one_at_a_time(ur5e):
    q = _random_q(50, 5)
    T = ur5e.fk(q)
    assert T.shape == (50, 4, 4)
    for i in range(50):
        assert np.allclose(ur5e.fk(q[i]), T[i], atol=1e-15)
    J = ur5e.jacobian(q)
    assert J.shape == (50, 6, 6) and ur5e.jacobian(q[0]).shape == (6, 6)


def test_base_and_tool_are_part_of_the_model(ur5e):
    T_wb = exp_se3([0.5, -0.2, 0.8, 0.0, 0.0, 0.7])
    T_ft = exp_se3([0.0, 0.0, 0.15, 0.0, 0.3, 0.0])
    m = ur5e.with_base(T_wb).with_tool(T_ft)
    q = _random_q(20, 6)
    assert np.allclose(m.fk(q), T_wb @ ur5e.fk(q) @ T_ft, atol=1e-14)
    assert np.allclose(m.fk(q, frame="base"), ur5e.fk(q) @ T_ft, atol=1e-14)
    assert np.allclose(m.T_world_base, T_wb) and np.allclose(m.T_flange_tcp, T_ft)
    d, a = pose_error(inv(m.T_world_base) @ m.fk(q[0]), m.fk(q[0], frame="base"))
    assert d < 1e-14 and a < 1e-12


def _potential_energy(m, qq, payload):
    """V = -sum_k m_k g . c_k (links and a payload at the TCP origin)."""
    F = m.link_frames(qq)
    V = np.zeros(qq.shape[0])
    for k, link in enumerate(m.links):
        c = F[:, k, :3, :3] @ np.array(link.com_link) + F[:, k, :3, 3]
        V -= link.mass_kg * c @ m.gravity_world
    return V - payload * m.fk(qq)[:, :3, 3] @ m.gravity_world


@pytest.mark.parametrize("name", ["ur5e", "abb_irb120"])
def test_gravity_torque_is_minus_the_gradient_of_potential_energy(name):
    """tau_j = -dV/dq_j, checked by central differences."""
    m = load_robot_model(name)
    q = _random_q(10, 7)
    h, payload = 1e-6, 2.0
    num = np.stack(
        [
            -(_potential_energy(m, q + h * e, payload) - _potential_energy(m, q - h * e, payload)) / (2 * h)
            for e in np.eye(6)
        ],
        axis=1,
    )
    assert np.allclose(m.gravity_torque(q, payload_kg=payload), num, atol=1e-6)
