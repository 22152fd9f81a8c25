"""Simulated controller: motion in simulated time, trapezoidal timing, linear moves, true-robot truth."""

from __future__ import annotations

import numpy as np
import pytest

from engine.transforms import exp_se3, log_so3
from plugins.robot.effects import Backlash, ThermalDrift
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects
from plugins.sim.clock import SimClock
from plugins.sim.controller import SimRobotController

UR5E = load_robot_model("ur5e")
HOME = UR5E.home


def make(effects=(), **kw):
    clock = SimClock()
    return clock, SimRobotController(UR5E, clock, true_robot=RobotWithEffects(UR5E, effects), **kw)


def test_movej_duration_is_distance_over_speed_plus_ramp():
    v, a = 0.5, 2.0
    durations = {}
    for dist in (0.4, 0.8, 1.6):
        _clock, ctl = make()
        target = HOME + np.array([dist, -dist / 2, 0, 0, 0, 0])
        res = ctl.move_j("m", target, speed=v, accel=a)
        assert res.accepted and res.start_s == 0.0
        durations[dist] = res.duration_s
        assert res.duration_s == pytest.approx(dist / v + v / a, rel=1e-12)  # leading axis = joint 1
    assert durations[0.8] - durations[0.4] == pytest.approx(0.4 / v, rel=1e-12)
    assert durations[1.6] - durations[0.8] == pytest.approx(0.8 / v, rel=1e-12)


def test_movej_speed_is_capped_by_the_joint_limit():
    _, ctl = make()
    res = ctl.move_j("m", HOME + np.array([2.0, 0, 0, 0, 0, 0]), speed=50.0, accel=5.0)
    vmax = UR5E.max_speed[0]
    assert res.duration_s == pytest.approx(2.0 / vmax + vmax / 5.0, rel=1e-12)


def test_time_passes_only_with_the_sim_clock():
    clock, ctl = make()
    target = HOME + 0.3
    res = ctl.move_j("m", target)
    assert ctl.state().moving and np.allclose(ctl.state().q, HOME)  # clock not advanced: still at start
    clock.advance(res.duration_s / 2)
    mid = ctl.state()
    assert mid.moving and np.allclose(mid.q, HOME + 0.15, atol=1e-12)  # symmetric profile: halfway
    assert np.allclose(mid.qd, mid.qd[0])  # synchronised axes, equal distances -> equal speeds
    clock.advance_to(res.end_s)
    end = ctl.state()
    assert not end.moving and np.allclose(end.q, target) and np.all(end.qd == 0)
    # the past stays queryable
    assert np.allclose(ctl.state(res.start_s + res.duration_s / 2).q, mid.q)


def test_movel_follows_a_straight_line_and_slerps_orientation():
    clock, ctl = make()
    T0 = ctl.state().T_base_tcp
    T1 = T0 @ exp_se3([0.0, 0.0, 0.0, 0.0, 0.0, 0.4])
    T1[:3, 3] += (0.12, -0.08, 0.1)
    res = ctl.move_l("l", T1, speed=0.2, accel=1.0)
    assert res.accepted, res.reason
    ts = np.linspace(res.start_s, res.end_s, 15)
    poses = [ctl.state(t).T_base_tcp for t in ts]
    P = np.array([T[:3, 3] for T in poses])
    u = (T1[:3, 3] - T0[:3, 3]) / np.linalg.norm(T1[:3, 3] - T0[:3, 3])
    d = P - T0[:3, 3]
    assert np.abs(d - np.outer(d @ u, u)).max() < 1e-9  # on the line
    s = d @ u / np.linalg.norm(T1[:3, 3] - T0[:3, 3])
    for T, si in zip(poses, s, strict=True):  # orientation at the same path fraction
        assert np.linalg.norm(log_so3(T[:3, :3].T @ (T0[:3, :3] @ exp_se3([0, 0, 0, 0, 0, 0.4 * si])[:3, :3]))) < 1e-6
    clock.advance_to(res.end_s)
    assert np.abs(ctl.state().T_base_tcp - T1).max() < 1e-9


def test_movel_duration_scales_with_distance():
    durations = []
    for dist in (0.1, 0.2):
        _, ctl = make()
        T = ctl.state().T_base_tcp.copy()
        T[0, 3] += dist
        res = ctl.move_l("l", T, speed=0.1, accel=0.5)
        assert res.accepted, res.reason
        durations.append(res.duration_s)
        assert res.duration_s == pytest.approx(dist / 0.1 + 0.1 / 0.5, rel=1e-9)
    assert durations[1] - durations[0] == pytest.approx(0.1 / 0.1, rel=1e-9)


def test_fast_movel_is_slowed_to_respect_joint_speeds():
    _clock, ctl = make()
    T = ctl.state().T_base_tcp.copy()
    T[:3, 3] += (0.3, 0.2, 0.0)
    res = ctl.move_l("l", T, speed=5.0, accel=50.0)
    assert res.accepted and res.duration_s > np.linalg.norm((0.3, 0.2)) / 5.0
    qd = np.array([ctl.state(t).qd for t in np.linspace(res.start_s, res.end_s, 200)])
    assert np.all(np.abs(qd) <= UR5E.max_speed * 1.05)  # 5 % for the waypoint-based speed estimate


def test_approach_direction_is_recorded_per_joint():
    clock, ctl = make(initial_direction=1.0)
    r = ctl.move_j("a", HOME + np.array([-0.2, 0.1, 0, 0, 0, 0]))
    clock.advance_to(r.end_s)
    assert np.array_equal(ctl.state().approach_direction, [-1, 1, 1, 1, 1, 1])
    r = ctl.move_j("b", HOME + np.array([-0.2, 0.1, -0.3, 0, 0, 0]))
    clock.advance_to(r.end_s)
    assert np.array_equal(ctl.state().approach_direction, [-1, 1, -1, 1, 1, 1])


def test_backlash_shows_in_the_true_pose_not_in_the_reported_one():
    b = 1e-3
    clock, ctl = make([Backlash((1,), (b,))])
    target = HOME.copy()
    poses = {}
    for cid, start in (("from_below", -0.2), ("from_above", 0.2)):
        r = ctl.move_j(cid + "_start", target + np.array([start, 0, 0, 0, 0, 0]))
        clock.advance_to(r.end_s)
        r = ctl.move_j(cid, target)
        clock.advance_to(r.end_s)
        st = ctl.state()
        poses[cid] = st
        assert np.allclose(st.q, target)
    a, b_ = poses["from_below"], poses["from_above"]
    assert np.allclose(a.T_base_tcp, b_.T_base_tcp)  # reported: identical
    assert a.q_actual[0] - b_.q_actual[0] == pytest.approx(-b, abs=1e-15)  # true: b apart
    radius = np.linalg.norm(a.T_base_tcp[:2, 3])
    gap = np.linalg.norm(a.T_world_tcp_actual[:3, 3] - b_.T_world_tcp_actual[:3, 3])
    assert gap == pytest.approx(b * radius, rel=1e-3)


def test_thermal_drift_moves_the_true_tcp_at_rest():
    drift = ThermalDrift(("base.tz",), (2e-4,), time_constant_s=600.0)
    clock, ctl = make([drift])
    z0 = ctl.state().T_world_tcp_actual[2, 3]
    clock.advance(600.0)
    z1 = ctl.state().T_world_tcp_actual[2, 3]
    clock.advance(6000.0)
    z2 = ctl.state().T_world_tcp_actual[2, 3]
    assert z1 - z0 == pytest.approx(2e-4 * (1 - np.exp(-1)), rel=1e-9)
    assert z2 - z0 == pytest.approx(2e-4, rel=1e-4)
    assert np.allclose(ctl.state().T_base_tcp, UR5E.fk(HOME))  # the controller does not know


def test_move_j_pose_reaches_a_cartesian_target():
    clock, ctl = make()
    T = UR5E.fk(HOME + np.array([0.3, -0.2, 0.2, 0.1, 0.2, -0.3]))
    r = ctl.move_j_pose("p", T)
    assert r.accepted, r.reason
    clock.advance_to(r.end_s)
    assert np.abs(ctl.state().T_base_tcp - T).max() < 1e-9


def test_halt_stops_a_joint_move_on_its_path_at_its_own_deceleration():
    clock, ctl = make()
    target = HOME + np.array([1.0, -0.5, 0, 0, 0, 0])
    res = ctl.move_j("m", target, speed=0.5, accel=2.0)  # 0.25 s ramps, cruise at 0.5 rad/s (joint 1)
    clock.advance(1.0)
    before = ctl.state()
    halted = ctl.halt()
    assert halted is not None and halted.halted and halted.accepted and ctl.result("m") == halted
    assert halted.end_s == pytest.approx(1.0 + 0.5 / 2.0, abs=1e-9)  # v / a: a stop at the move's deceleration
    assert halted.end_s < res.end_s
    now = ctl.state()  # the halt does not jump: position and speed go on from where they were
    assert np.allclose(now.q, before.q, atol=1e-12) and np.allclose(now.qd, before.qd, atol=1e-12)
    assert np.allclose(ctl.state(1.1).qd[0], 0.5 - 2.0 * 0.1, atol=1e-9)  # decelerating
    q_rest = HOME + np.array([0.5, -0.25, 0, 0, 0, 0])  # 0.4375 rad by the halt + 0.0625 braking
    for t in (halted.end_s, halted.end_s + 5.0):
        st = ctl.state(t)
        assert not st.moving and np.allclose(st.q, q_rest, atol=1e-9) and np.all(st.qd == 0)
    assert ctl.halt() is not None  # still braking: a second halt changes nothing
    assert ctl.result("m").end_s == halted.end_s
    clock.advance_to(halted.end_s)
    assert ctl.halt() is None  # at rest: nothing to halt
    assert ctl.move_j("next", HOME).accepted  # not busy: the halted move is over


def test_halt_stops_a_linear_move_on_its_line_short_of_the_target():
    clock, ctl = make()
    T0 = ctl.state().T_base_tcp
    T1 = T0.copy()
    T1[:3, 3] += (0.2, 0.0, 0.0)
    res = ctl.move_l("l", T1, speed=0.1, accel=0.5)
    clock.advance(res.duration_s / 2)
    halted = ctl.halt()
    assert halted is not None and halted.end_s < res.end_s
    clock.advance_to(halted.end_s)
    rest = ctl.state()
    d = rest.T_base_tcp[:3, 3] - T0[:3, 3]
    assert not rest.moving
    assert np.abs(d[1:]).max() < 1e-9 and 0.1 < d[0] < 0.2 - 1e-3  # on the line, past halfway, short of it
