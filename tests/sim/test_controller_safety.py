"""Simulated controller safety: refusals leave the robot still, command ids are idempotent."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.transforms import T_from_Rt
from plugins.robot.model_file import load_robot_model
from plugins.sim.clock import SimClock
from plugins.sim.controller import SimRobotController

UR5E = load_robot_model("ur5e")
IRB120 = load_robot_model("abb_irb120")


def make(model=UR5E):
    clock = SimClock()
    return clock, SimRobotController(model, clock)


def assert_still(clock, ctl, q0):
    clock.advance(10.0)
    st_ = ctl.state()
    assert not st_.moving and np.array_equal(st_.q, q0)


def test_out_of_limit_joint_target_is_refused_without_motion():
    clock, ctl = make(IRB120)
    q0 = ctl.state().q
    res = ctl.move_j("x", np.radians([170, 0, 0, 0, 0, 0]))
    assert not res.accepted and "axis1" in res.reason and "170.000 deg" in res.reason
    assert res.duration_s == 0
    assert_still(clock, ctl, q0)


def test_unreachable_targets_are_refused_without_motion():
    clock, ctl = make()
    q0 = ctl.state().q
    far = T_from_Rt(np.eye(3), (1.5, 0.0, 0.3))
    for res in (ctl.move_l("l", far), ctl.move_j_pose("j", far)):
        assert not res.accepted and "unreachable" in res.reason
    assert_still(clock, ctl, q0)


def test_cartesian_target_only_reachable_out_of_limits_is_refused():
    clock, ctl = make(IRB120)
    q0 = ctl.state().q
    T = IRB120.fk(np.radians([175.0, 10.0, 5.0, 0.0, 30.0, 0.0]))
    res = ctl.move_j_pose("j", T)
    assert not res.accepted and "out_of_limits" in res.reason
    assert_still(clock, ctl, q0)


def test_linear_path_through_the_workspace_boundary_is_refused():
    """Both ends reachable, but the straight line between them passes the base axis singularity."""
    clock, ctl = make()
    q0 = ctl.state().q
    T0 = ctl.state().T_base_tcp
    T1 = T0.copy()
    T1[:2, 3] = -T0[:2, 3]  # mirror through the base axis: the line crosses the unreachable cylinder
    res = ctl.move_l("l", T1)
    assert not res.accepted, res
    assert "path" in res.reason or "singular" in res.reason
    assert_still(clock, ctl, q0)


def test_duplicate_command_id_never_moves_twice():
    clock, ctl = make()
    q0 = ctl.state().q
    first = ctl.move_j("cmd-1", q0 + 0.2)
    clock.advance_to(first.end_s)
    back = ctl.move_j("cmd-2", q0)
    clock.advance_to(back.end_s)
    again = ctl.move_j("cmd-1", q0 + 0.2)
    assert again.duplicate and again.accepted and again.start_s == first.start_s and again.end_s == first.end_s
    assert_still(clock, ctl, q0)
    # a duplicate id with a different target is not executed either
    other = ctl.move_j("cmd-2", q0 - 0.3)
    assert other.duplicate and np.allclose(other.q_target, q0)
    assert_still(clock, ctl, q0)
    # refusals are remembered too: retrying needs a new id
    bad = ctl.move_j("cmd-3", q0 + 100)
    assert not bad.accepted and ctl.move_j("cmd-3", q0 + 0.1).duplicate
    assert_still(clock, ctl, q0)


def test_busy_controller_refuses_a_second_move():
    clock, ctl = make()
    q0 = ctl.state().q
    first = ctl.move_j("a", q0 + 0.5)
    clock.advance(first.duration_s / 3)
    res = ctl.move_j("b", q0)
    assert not res.accepted and "busy" in res.reason
    clock.advance_to(first.end_s)
    assert np.allclose(ctl.state().q, q0 + 0.5)


joint_vals = st.floats(-3, 3, allow_nan=False)


@given(st.lists(joint_vals, min_size=6, max_size=6), st.integers(0, 5), st.sampled_from([np.nan, np.inf]))
@settings(max_examples=25, deadline=None)
def test_non_finite_joint_targets_are_refused(q, k, bad):
    clock, ctl = make()
    q0 = ctl.state().q
    q = np.array(q)
    q[k] = bad
    res = ctl.move_j("x", q)
    assert not res.accepted and "NaN" in res.reason
    assert_still(clock, ctl, q0)


@given(st.integers(0, 9).filter(lambda n: n != 6))
@settings(max_examples=10, deadline=None)
def test_wrong_length_joint_targets_are_refused(n):
    clock, ctl = make()
    q0 = ctl.state().q
    res = ctl.move_j("x", np.zeros(n))
    assert not res.accepted and "6 joints" in res.reason
    assert_still(clock, ctl, q0)


@given(st.floats(1.01, 3.0), st.sampled_from(["l", "j"]))
@settings(max_examples=10, deadline=None)
def test_non_rigid_cartesian_targets_are_refused(scale, kind):
    clock, ctl = make()
    q0 = ctl.state().q
    T = ctl.state().T_base_tcp.copy()
    T[:3, :3] *= scale
    res = ctl.move_l("x", T) if kind == "l" else ctl.move_j_pose("x", T)
    assert not res.accepted and "not a rotation" in res.reason
    assert_still(clock, ctl, q0)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_speed_or_acceleration_is_refused(bad):
    clock, ctl = make()
    q0 = ctl.state().q
    assert "speed" in ctl.move_j("a", q0 + 0.1, speed=bad).reason
    assert "accel" in ctl.move_j("b", q0 + 0.1, accel=bad).reason
    T = ctl.state().T_base_tcp.copy()
    T[0, 3] += 0.05
    assert "speed" in ctl.move_l("c", T, speed=bad).reason
    assert_still(clock, ctl, q0)


def test_bad_construction_and_clock():
    clock = SimClock()
    with pytest.raises(ValueError, match="out of limits"):
        SimRobotController(IRB120, clock, q_initial=np.radians([170, 0, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="NaN"):
        SimRobotController(UR5E, clock, q_initial=[np.nan] * 6)
    with pytest.raises(ValueError, match="command_id"):
        SimRobotController(UR5E, clock).move_j("", UR5E.home)
    with pytest.raises(ValueError, match="forward"):
        clock.advance(-1.0)
    clock.advance(2.0)
    with pytest.raises(ValueError, match="back"):
        clock.advance_to(1.0)


def test_history_is_bounded_and_never_guessed():
    """A controller running for months keeps its last moves only: the state inside that history is
    exact (same as a controller keeping everything), before it is refused, and an id older than the
    kept results is a new command."""
    clock_a = SimClock()
    keep_all = SimRobotController(UR5E, clock_a, keep_moves=100)
    clock_b = SimClock()
    bounded = SimRobotController(UR5E, clock_b, keep_moves=3)
    home = UR5E.home
    t_marks = []
    for i in range(8):
        q = home + np.radians([5.0 * (i % 2), -3.0, 2.0, 0.0, 1.0 * i, 0.0])
        for clock, ctl in ((clock_a, keep_all), (clock_b, bounded)):
            assert ctl.move_j(f"m{i}", q).accepted
            clock.advance(5.0)
        t_marks.append(clock_b.now_s())
    assert len(bounded._segments) == 3 and len(bounded._results) == 8
    for t in np.linspace(t_marks[-3] - 4.0, t_marks[-1] + 1.0, 25):  # inside the kept 3 moves
        a, b = keep_all.state(t), bounded.state(t)
        assert np.array_equal(a.q, b.q) and np.array_equal(a.approach_direction, b.approach_direction)
    with pytest.raises(ValueError, match="before the 3 moves"):
        bounded.state(t_marks[0])
    assert bounded.move_j("m7", home).duplicate  # a kept id is still idempotent
    for i in range(8, 20):
        clock_b.advance(5.0)
        bounded.move_j(f"r{i}", home)
    fresh = bounded.move_j("m0", home)  # forgotten: a new command (home: already there, nothing moves)
    assert not fresh.duplicate


def test_keep_moves_must_hold_at_least_two():
    with pytest.raises(ValueError, match="keep_moves"):
        SimRobotController(UR5E, SimClock(), keep_moves=1)
