"""``sim_robot`` publishes its state along every move at ``state_rate_hz`` of simulated time.

The samples follow the controller's motion profile: their number is the move's duration times the
rate, their stamps lie on the rate's grid from the command's time, and the poses lie on the
commanded path (a straight joint-space line for move_j, a straight TCP line with slerped
orientation for move_l) at the trapezoid's path parameter.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from adapter_context import make_stage

from engine.messages import RobotCommand
from engine.transforms import log_so3
from plugins.sim import controller as ctl
from plugins.sim.motion_profile import trapezoid
from plugins.sim.stages.robot import SimRobot

STREAMS = ("joint_state", "tcp_pose", "frames", "truth/tcp_pose")


def robot(**params):
    stage, ctx = make_stage(SimRobot, {"model": "ur5e", **params}, name="robot")
    stage.setup()
    return stage, ctx


def counts(ctx) -> dict[str, int]:
    return {port: len(ctx.published[port]) for port in STREAMS}


def expected_samples(duration_s: float, rate_hz: float) -> int:
    """Samples of one move: the grid points t0 + k / rate inside the move, and the one at rest."""
    end_ns = round(duration_s * 1e9)
    return sum(1 for k in range(1, 100_000) if round(k * 1e9 / rate_hz) < end_ns) + 1


def move(stage, ctx, cmd: RobotCommand):
    before, t0 = counts(ctx), ctx.clock.now_ns()
    reply = stage.on_request("move", cmd)
    assert reply.ok, reply.error
    new = {port: ctx.published[port][before[port] :] for port in STREAMS}
    return reply, t0, new


@pytest.mark.parametrize("rate_hz", [25.0, 7.0, 100.0])
def test_move_j_publishes_duration_times_rate_samples_on_the_joint_line(rate_hz):
    stage, ctx = robot(state_rate_hz=rate_hz)
    assert counts(ctx) == dict.fromkeys(STREAMS, 1)  # at set-up
    q0 = stage.ctl.state().q
    q1 = q0 + np.array([0.6, -0.3, 0.4, 0.0, 0.2, -0.5])
    reply, t0, new = move(stage, ctx, RobotCommand(command_id="j1", kind="move_j", joints=q1))
    n = expected_samples(reply.duration_s, rate_hz)
    assert abs(n - reply.duration_s * rate_hz) <= 1 and n == math.ceil(reply.duration_s * rate_hz)
    assert {port: len(msgs) for port, msgs in new.items()} == dict.fromkeys(STREAMS, n)
    stamps = [m.stamp_ns for m in new["joint_state"]]
    assert stamps[:-1] == [t0 + round(k * 1e9 / rate_hz) for k in range(1, n)]  # the rate's grid
    # at rest when the move ends (the controller keeps seconds since the epoch in float64: ~0.2 us)
    assert stamps[-1] == ctx.clock.now_ns() and stamps[-1] - t0 == pytest.approx(reply.duration_s * 1e9, abs=1e3)
    for port in ("tcp_pose", "frames", "truth/tcp_pose"):
        assert [m.stamp_ns for m in new[port]] == stamps
    # on the line q0 + s (q1 - q0), at the trapezoid's s(t) (leading axis: joint 1, 0.6 rad); the
    # controller's times are float64 seconds since the epoch (~0.2 us), hence the tolerances
    dq = q1 - q0
    profile = trapezoid(1.0, ctl.MOVEJ_SPEED / 0.6, ctl.MOVEJ_ACCEL / 0.6)
    assert reply.duration_s == pytest.approx(profile.duration, abs=1e-6)
    Q = np.array([m.positions for m in new["joint_state"]])
    s = (Q - q0) @ dq / (dq @ dq)
    np.testing.assert_allclose(Q, q0 + s[:, None] * dq, atol=1e-12)
    np.testing.assert_allclose(s, profile.position((np.array(stamps) - t0) / 1e9), atol=1e-6)
    assert np.all(np.diff(s) > 0) and s[0] > 0 and s[-1] == pytest.approx(1.0, abs=1e-12)
    V = np.array([m.velocities for m in new["joint_state"]])
    assert np.all(V[:-1] @ dq > 0) and np.all(V[-1] == 0)  # moving forward, at rest at the end
    # the TCP pose and the frame tree of each sample are the nominal FK of its joints
    for js, tcp, frames in zip(new["joint_state"], new["tcp_pose"], new["frames"], strict=True):
        T = stage.nominal.fk(js.positions, frame="base")
        np.testing.assert_allclose(tcp.T, T, atol=1e-12)
        edges = {(t.frame_id, t.child_frame_id): t.T for t in frames.transforms}
        np.testing.assert_allclose(edges[("base", "tcp")], T, atol=1e-9)  # via the wire's quaternion


def test_move_l_samples_lie_on_the_straight_line_with_slerped_orientation():
    stage, ctx = robot()  # default 25 Hz
    T0 = stage.ctl.state().T_base_tcp
    T1 = T0.copy()
    T1[:3, 3] += [0.10, -0.05, 0.08]
    c, s_ = math.cos(0.3), math.sin(0.3)
    T1[:3, :3] = T0[:3, :3] @ np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    reply, _, new = move(stage, ctx, RobotCommand(command_id="l1", kind="move_l", T=T1))
    n = len(new["tcp_pose"])
    assert n == expected_samples(reply.duration_s, 25.0) and n > 10
    P = np.array([m.T[:3, 3] for m in new["tcp_pose"]])
    dp = T1[:3, 3] - T0[:3, 3]
    s_pos = (P - T0[:3, 3]) @ dp / (dp @ dp)
    off_line = np.linalg.norm(P - T0[:3, 3] - s_pos[:, None] * dp, axis=1)
    assert off_line.max() < 1e-9  # metres from the commanded line
    phi = log_so3(T0[:3, :3].T @ T1[:3, :3])
    for m, s in zip(new["tcp_pose"], s_pos, strict=True):
        rel = log_so3(T0[:3, :3].T @ m.T[:3, :3])
        np.testing.assert_allclose(rel, s * phi, atol=1e-9)  # same path parameter for the orientation
    assert np.all(np.diff(s_pos) > 0) and s_pos[-1] == pytest.approx(1.0, abs=1e-12)
    # truth (no effects here): the same poses in the world frame
    for tcp, truth in zip(new["tcp_pose"], new["truth/tcp_pose"], strict=True):
        assert truth.frame_id == "world" and truth.stamp_ns == tcp.stamp_ns
        np.testing.assert_allclose(truth.T, stage.nominal.T_world_base @ tcp.T, atol=1e-12)


def test_truth_follows_the_motion_with_the_robot_effects():
    stage, ctx = robot(effects={"joint_compliance": {"joints": [2, 3], "compliance_rad_per_nm": [2e-5, 2e-5]}})
    q1 = stage.ctl.state().q + np.array([0.0, -0.4, 0.5, 0.0, 0.0, 0.0])
    _, _, new = move(stage, ctx, RobotCommand(command_id="j", kind="move_j", joints=q1))
    gaps = [
        np.linalg.norm(truth.T[:3, 3] - (stage.nominal.T_world_base @ tcp.T)[:3, 3])
        for tcp, truth in zip(new["tcp_pose"], new["truth/tcp_pose"], strict=True)
    ]
    assert min(gaps) > 1e-5 and np.ptp(gaps) > 1e-6  # the sag changes along the path


def test_rate_zero_publishes_at_rest_only_and_a_duplicate_publishes_nothing():
    stage, ctx = robot(state_rate_hz=0.0)
    q1 = stage.ctl.state().q + 0.3
    move(stage, ctx, RobotCommand(command_id="a", kind="move_j", joints=q1))
    assert counts(ctx) == dict.fromkeys(STREAMS, 2)  # set-up and at rest
    stage2, ctx2 = robot()
    move(stage2, ctx2, RobotCommand(command_id="a", kind="move_j", joints=q1))
    after = counts(ctx2)
    reply = stage2.on_request("move", RobotCommand(command_id="a", kind="move_j", joints=q1))
    assert reply.duplicate and counts(ctx2) == after
    refused = stage2.on_request("move", RobotCommand(command_id="b", kind="move_j", joints=q1 + 10.0))
    assert not refused.ok and counts(ctx2) == after
