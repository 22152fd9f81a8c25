"""Numerical IK: FK/IK round trips within the joint limits, and clear failures."""

from __future__ import annotations

import numpy as np
import pytest

from engine.transforms import T_from_Rt, exp_se3, pose_error
from plugins.robot.model_file import load_robot_model


@pytest.fixture(scope="module", params=["ur5e", "abb_irb120"])
def model(request):
    return load_robot_model(request.param).with_tool(exp_se3([0.0, 0.0, 0.12, 0.0, 0.0, 0.0]))


def _reachable_configs(model, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi)
    return lo + rng.random((n, model.dof)) * (hi - lo)


def test_round_trip_from_random_seeds(model):
    """IK of FK(q) from the default seed recovers the pose to 1 um / 1 urad, inside the limits."""
    q_true = _reachable_configs(model, 25, seed=10)
    for q in q_true:
        T = model.fk(q)
        res = model.ik(T)
        assert res.success, res.reason
        assert model.within_limits(res.q)
        d, a = pose_error(model.fk(res.q), T)
        assert d < 1e-6 and a < 1e-6


def test_round_trip_from_a_nearby_seed_keeps_the_branch(model):
    q_true = _reachable_configs(model, 25, seed=11)
    for q in q_true:
        res = model.ik(model.fk(q), q + 0.05)
        assert res.success and res.attempts == 1
        assert np.allclose(res.q, q, atol=1e-6)


def test_position_only(model):
    q = _reachable_configs(model, 1, seed=12)[0]
    T = model.fk(q) @ exp_se3([0, 0, 0, 0.4, 0.3, 0.2])  # orientation that may not be reachable
    res = model.ik(T, position_only=True)
    assert res.success and np.linalg.norm(model.fk(res.q)[:3, 3] - T[:3, 3]) < 1e-6


def test_far_target_is_unreachable(model):
    res = model.ik(T_from_Rt(np.eye(3), (3.0, 0.0, 0.5)))
    assert not res.success and res.status == "unreachable" and res.q is None
    assert "mm" in res.reason


def test_target_inside_the_sphere_but_not_reachable_in_that_orientation():
    """UR5e: flange 2 cm above the base origin, pointing up (inside the reach sphere).

    The wrist-2 centre would then sit on the joint-1 axis (0, 0, 0.02 - d6); UR's analytic IK needs
    it at least d4 = 0.1333 m from that axis (the shoulder offset), so no solution exists.
    """
    m = load_robot_model("ur5e")
    res = m.ik(T_from_Rt(np.eye(3), (0.0, 0.0, 0.02)), n_random_seeds=4)
    assert res.status == "unreachable", res


def test_out_of_limits_is_told_apart():
    """IRB 120: a pose made with axis 1 at 175 deg (limit 165) is only reachable outside the limits."""
    m = load_robot_model("abb_irb120")
    T = m.fk(np.radians([175.0, 10.0, 5.0, 0.0, 30.0, 0.0]))
    res = m.ik(T)
    assert not res.success and res.status == "out_of_limits"
    assert "outside" in res.reason and "deg" in res.reason


@pytest.mark.parametrize(
    "bad",
    [np.full((4, 4), np.nan), np.diag([1.0, 1.0, 2.0, 1.0]), np.eye(3)],
    ids=["nan", "scaled", "3x3"],
)
def test_malformed_target_raises(model, bad):
    with pytest.raises(ValueError):
        model.ik(bad)
