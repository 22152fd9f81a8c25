"""ur_robot against a fake ur-rtde: conversions, idempotent ids, refusals without motion, SDK errors."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest
from adapter_context import make_stage
from fake_ur_rtde import IP, FakeURController, install
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from engine import transforms as tf
from engine.messages import Request, RobotCommand
from plugins import vendor_poses
from plugins.devices.stages.ur_robot import URRobot
from plugins.devices.ur_rtde_driver import URConnectionError
from plugins.util.sdk import MissingSDKError

PARAMS = {"ip": IP, "workspace_min_m": (-0.8, -0.6, 0.05), "workspace_max_m": (0.2, 0.6, 0.8)}


@pytest.fixture
def ctl(monkeypatch) -> FakeURController:
    c = FakeURController()
    install(monkeypatch, c)
    return c


def robot(ctl: FakeURController, **params):
    stage, ctx = make_stage(URRobot, {**PARAMS, **params})
    stage.setup()
    return stage, ctx


def home_T(ctl: FakeURController) -> np.ndarray:
    return vendor_poses.T_from_ur(ctl.tcp_vector())


def nudged(T: np.ndarray, dx=0.0, dy=0.0, dz=0.0, rot_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    """T moved by (dx, dy, dz) in base and rotated about the TCP by a rotation vector in degrees."""
    out = T @ tf.T_from_rotvec(np.radians(rot_deg))
    out[:3, 3] += (dx, dy, dz)
    return out


def move_l(cid: str, T, **kw) -> RobotCommand:
    return RobotCommand(command_id=cid, kind="move_l", T=T, frame_id="base", **kw)


# ----------------------------------------------------------------------------- conversions / motion


def test_move_l_sends_the_ur_vector_of_the_target_and_reports_the_reached_pose(ctl):
    stage, ctx = robot(ctl)
    T = nudged(home_T(ctl), dx=0.01, dz=-0.02, rot_deg=(0, 0, 5))
    reply = stage.on_request("move", move_l("a", T))
    assert reply.ok and not reply.duplicate and reply.error == ""
    [(name, (pose, speed, accel, asynchronous))] = ctl.move_calls()
    assert name == "moveL" and asynchronous is False
    assert (speed, accel) == (0.05, 0.25)  # the stage defaults, not ur-rtde's
    np.testing.assert_allclose(pose, vendor_poses.ur_from_T(T), atol=1e-12)
    np.testing.assert_allclose(vendor_poses.T_from_ur(pose), T, atol=1e-12)
    assert tf.pose_error(reply.T, T)[0] < 1e-6 and tf.pose_error(reply.T, T)[1] < 1e-6
    # state published at set-up and after the command, consistent with the reply
    assert len(ctx.published["tcp_pose"]) == 2 and len(ctx.published["joint_state"]) == 2
    np.testing.assert_allclose(ctx.published["tcp_pose"][-1].T, reply.T, atol=1e-12)
    np.testing.assert_allclose(ctx.published["joint_state"][-1].positions, reply.joints, atol=1e-12)
    frames = ctx.published["frames"][-1].transforms
    assert [(f.frame_id, f.child_frame_id) for f in frames] == [("world", "base"), ("base", "tcp")]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    axis=st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda v: np.linalg.norm(v) > 1e-3),
    angle=st.floats(0.0, math.pi),
    t=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
)
def test_ur_pose_vector_round_trip_including_rotations_near_pi(axis, angle, t):
    rotvec = np.asarray(axis) / np.linalg.norm(axis) * angle
    T = tf.T_from_rotvec(rotvec, t)
    back = vendor_poses.T_from_ur(vendor_poses.ur_from_T(T))
    assert tf.pose_error(back, T)[0] < 1e-12 and tf.pose_error(back, T)[1] < 1e-9


def test_state_service_and_state_command_read_without_moving(ctl):
    stage, _ = robot(ctl)
    for reply in (
        stage.on_request("state", Request(command="now")),
        stage.on_request("move", RobotCommand(kind="state")),
    ):
        assert reply.ok and reply.frame_id == "base"
        np.testing.assert_allclose(reply.T, home_T(ctl), atol=1e-12)
        np.testing.assert_allclose(reply.joints, ctl.q, atol=0)
    assert ctl.move_calls() == []


def test_move_j_to_joints_checks_the_target_tcp_with_the_controller_fk_then_moves(ctl):
    stage, _ = robot(ctl)
    q = ctl.q + np.radians([5, -3, 4, 2, -2, 10])
    reply = stage.on_request("move", RobotCommand(command_id="j1", kind="move_j", joints=q, speed=0.5))
    assert reply.ok, reply.error
    assert [c[0] for c in ctl.calls if c[0] in ("getForwardKinematics", "moveJ")] == ["getForwardKinematics", "moveJ"]
    assert ctl.move_calls()[0][1][1:] == (0.5, 0.5, False)  # requested speed, default accel, blocking
    np.testing.assert_allclose(reply.joints, q, atol=1e-12)


def test_move_j_to_a_pose_moves_to_the_controllers_ik_joints_checked_first(ctl):
    stage, _ = robot(ctl)
    T = nudged(home_T(ctl), dy=0.02)
    reply = stage.on_request("move", RobotCommand(command_id="jp", kind="move_j", T=T))
    assert reply.ok, reply.error
    assert [c[0] for c in ctl.calls if c[0] in ("getInverseKinematics", "getForwardKinematics", "moveJ")] == [
        "getInverseKinematics",
        "getForwardKinematics",
        "moveJ",
    ]
    assert tf.pose_error(reply.T, T)[0] < 1e-6


@pytest.mark.parametrize(
    ("setup", "says"),
    [
        # the 20 mm step turns joints 1 and 6 by -2.3 deg: a recipe limit at -1 deg on joint 1 ...
        ({"joint_min_deg": [-1.0, -360, -360, -360, -360, -360]}, "joint 1 target"),
        ({"max_joint_step_deg": 1.0}, "step limit"),  # ... or a 1 deg joint step limit refuses it
    ],
)
def test_move_j_to_a_pose_is_refused_when_the_ik_joints_break_a_joint_limit(ctl, setup, says):
    """The TCP step and workspace are fine, but the joints the controller would take are not: the
    recipe's joint limits hold for pose targets too (moveJ_IK would have gone there unchecked)."""
    stage, _ = robot(ctl, **setup)
    T = nudged(home_T(ctl), dy=0.02)
    reply = stage.on_request("move", RobotCommand(command_id="jp", kind="move_j", T=T))
    assert not reply.ok and says in reply.error and ctl.move_calls() == []


@pytest.mark.parametrize(("answer", "says"), [("raises", "found no joints"), ("elsewhere", "from the target pose")])
def test_move_j_to_a_pose_without_a_sound_ik_answer_does_not_move(ctl, answer, says):
    ctl.ik_answer = answer
    stage, _ = robot(ctl)
    reply = stage.on_request("move", RobotCommand(command_id="jp", kind="move_j", T=nudged(home_T(ctl), dy=0.02)))
    assert not reply.ok and says in reply.error and ctl.move_calls() == []


# ----------------------------------------------------------------------------- idempotency


def test_a_repeated_command_id_returns_the_first_reply_and_does_not_move(ctl):
    stage, ctx = robot(ctl)
    T1 = nudged(home_T(ctl), dx=0.01)
    first = stage.on_request("move", move_l("same", T1))
    T2 = nudged(home_T(ctl), dx=-0.01)  # a different target under the same id must not run either
    again = stage.on_request("move", move_l("same", T2))
    assert first.ok and again.ok and again.duplicate and not first.duplicate
    np.testing.assert_array_equal(again.T, first.T)
    assert len(ctl.move_calls()) == 1
    assert len(ctx.published["tcp_pose"]) == 2  # no publication for the duplicate


def test_a_refused_id_stays_refused_when_repeated(ctl):
    stage, _ = robot(ctl)
    far = nudged(home_T(ctl), dx=0.2)
    first = stage.on_request("move", move_l("x", far))
    ok_target = nudged(home_T(ctl), dx=0.01)
    again = stage.on_request("move", move_l("x", ok_target))
    assert not first.ok and not again.ok and again.duplicate and again.error == first.error
    assert ctl.move_calls() == []


def test_command_journal_keeps_ids_across_runs_and_never_repeats_an_unfinished_one(ctl, tmp_path):
    journal = tmp_path / "ids.jsonl"
    stage, _ = robot(ctl, command_journal=str(journal))
    assert stage.on_request("move", move_l("m1", nudged(home_T(ctl), dx=0.01))).ok
    stage.teardown()
    rows = [json.loads(line) for line in journal.read_text().splitlines()]
    assert [(r["command_id"], r["phase"]) for r in rows] == [("m1", "started"), ("m1", "done")]
    with journal.open("a") as f:  # a run that died during the motion of m2
        f.write(json.dumps({"command_id": "m2", "phase": "started"}) + "\n")
    stage2, _ = robot(ctl, command_journal=str(journal))
    again = stage2.on_request("move", move_l("m1", nudged(home_T(ctl), dx=0.01)))
    unknown = stage2.on_request("move", move_l("m2", nudged(home_T(ctl), dx=0.01)))
    assert again.duplicate and again.ok
    assert unknown.duplicate and not unknown.ok and "outcome is unknown" in unknown.error
    assert len(ctl.move_calls()) == 1


def test_a_corrupt_journal_is_an_error_naming_the_line(ctl, tmp_path):
    journal = tmp_path / "ids.jsonl"
    journal.write_text('{"command_id": "a", "phase": "done", "ok": true}\nnot json\n')
    with pytest.raises(ValueError, match=r"ids.jsonl:2"):
        robot(ctl, command_journal=str(journal))


# ----------------------------------------------------------------------------- refusals (no motion)

NAN_T = np.eye(4)
NAN_T[0, 3] = np.nan
SCALED_T = np.diag([1.01, 1.0, 1.0, 1.0])


@pytest.mark.parametrize(
    ("make_cmd", "expect"),
    [
        (lambda T: move_l("nan", NAN_T), "NaN"),
        (lambda T: move_l("scaled", nudged(T) @ SCALED_T), "not a rotation"),
        (lambda T: move_l("noT", None), "no target pose"),
        (lambda T: move_l("below", nudged(T, dz=-0.45)), "z = "),
        (lambda T: move_l("far", nudged(T, dx=0.06)), "step limit is 50.0 mm"),
        (lambda T: move_l("turn", nudged(T, rot_deg=(0, 20, 0))), "step limit is 15.00 deg"),
        (lambda T: move_l("fast", nudged(T, dx=0.01), speed=0.3), "speed 0.3 m/s exceeds the configured maximum 0.25"),
        (lambda T: move_l("acc", nudged(T, dx=0.01), acceleration=2.0), "acceleration 2 m/s^2 exceeds"),
        (lambda T: move_l("neg", nudged(T, dx=0.01), speed=-1.0), "not a non-negative number"),
        (lambda T: RobotCommand(command_id="world", kind="move_l", T=nudged(T, dx=0.01), frame_id="world"), "'world'"),
        (lambda T: move_l("", nudged(T, dx=0.01)), "command_id must be a non-empty string"),
        (lambda T: RobotCommand(command_id="none", kind="move_j"), "move_j needs joints or a target pose T"),
        (lambda T: RobotCommand(command_id="qnan", kind="move_j", joints=[0, np.nan, 0, 0, 0, 0]), "NaN"),
        (lambda T: RobotCommand(command_id="q5", kind="move_j", joints=[0, 0, 0, 0, 0]), "has 5 values"),
        (
            lambda T: RobotCommand(command_id="qlim", kind="move_j", joints=np.radians([0, -90, 90, -90, -90, 370])),
            "joint 6 target 370.00 deg is outside its limits",
        ),
        (
            lambda T: RobotCommand(command_id="qstep", kind="move_j", joints=np.radians([40, -90, 90, -90, -90, 0])),
            "joint 1 would move 40.00 deg",
        ),
        (
            lambda T: RobotCommand(
                command_id="qbox",
                kind="move_j",
                joints=np.radians([0, -90, 90, -90, -90, 0]) + np.radians([25, 0, 0, 0, 0, 0]),
            ),
            "TCP of the joint target y = ",
        ),
    ],
)
def test_bad_targets_are_refused_with_the_reason_and_no_move_call(ctl, make_cmd, expect):
    stage, _ = robot(ctl, workspace_min_m=(-0.8, -0.3, 0.05), workspace_max_m=(0.2, 0.2, 0.8))
    reply = stage.on_request("move", make_cmd(home_T(ctl)))
    assert not reply.ok and expect in reply.error, reply.error
    assert ctl.move_calls() == []
    np.testing.assert_allclose(reply.T, home_T(ctl), atol=1e-12)  # the current pose, so the caller knows


@pytest.mark.parametrize(
    ("fault", "expect"),
    [
        ({"connected": False}, f"not connected to the UR controller at {IP}"),
        ({"protective_stopped": True, "safety_mode": 3}, "protective stop"),
        ({"emergency_stopped": True, "safety_mode": 7}, "emergency-stopped"),
        ({"safety_mode": 9}, "safety mode is FAULT"),
        ({"robot_mode": 3}, "robot mode is POWER_OFF"),
        ({"program_running": False}, "control script is not running"),
        ({"fk_fails": True}, "gave no TCP pose for the joint target"),
    ],
)
def test_controller_faults_refuse_before_any_motion(ctl, fault, expect):
    stage, ctx = robot(ctl)
    for k, v in fault.items():
        setattr(ctl, k, v)
    q = ctl.q + np.radians([2, 0, 0, 0, 0, 0])
    for cmd in (move_l("l", nudged(home_T(ctl), dx=0.01)), RobotCommand(command_id="j", kind="move_j", joints=q)):
        reply = stage.on_request("move", cmd)
        if expect.startswith("gave no TCP") and cmd.kind == "move_l":
            assert reply.ok  # FK is only needed for joint targets
            continue
        assert not reply.ok and expect in reply.error, reply.error
    assert [c[0] for c in ctl.move_calls()] == (["moveL"] if "fk_fails" in fault else [])
    assert any(e.code == "robot_refused" for e in ctx.events)


def test_read_only_connects_without_control_and_refuses_moves(ctl):
    stage, _ = robot(ctl, control=False)
    assert not any(c[0] == "RTDEControlInterface" for c in ctl.calls)
    reply = stage.on_request("move", move_l("ro", nudged(home_T(ctl), dx=0.01)))
    assert not reply.ok and "read-only" in reply.error
    assert stage.on_request("state", Request()).ok


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    delta=st.lists(
        st.one_of(st.floats(-0.1, 0.1), st.floats(-1.0, 1.0), st.sampled_from([np.nan, np.inf])), min_size=3, max_size=3
    ),
    rot=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    bad_entry=st.one_of(
        st.none(), st.tuples(st.integers(0, 3), st.integers(0, 3), st.sampled_from([np.nan, np.inf, 2.0]))
    ),
)
def test_no_target_outside_the_limits_ever_reaches_the_controller(monkeypatch, delta, rot, bad_entry):
    ctl = FakeURController()
    install(monkeypatch, ctl)
    stage, _ = robot(ctl)
    T0 = home_T(ctl)
    T = nudged(T0, *[0.0 if not np.isfinite(d) else d for d in delta], rot_deg=np.degrees(rot))
    if not all(np.isfinite(delta)):
        T[0, 3] = np.nan
    if bad_entry is not None:
        T[bad_entry[0], bad_entry[1]] = bad_entry[2]
    reply = stage.on_request("move", move_l("h", T))
    finite_rigid = np.all(np.isfinite(T)) and tf.is_rotation(T[:3, :3]) and np.allclose(T[3], [0, 0, 0, 1])
    allowed = False
    if finite_rigid:
        dist, ang = tf.pose_error(T0, T)
        inside = np.all(T[:3, 3] >= PARAMS["workspace_min_m"]) and np.all(T[:3, 3] <= PARAMS["workspace_max_m"])
        allowed = bool(inside and dist <= 0.05 and ang <= math.radians(15))
    assert reply.ok == allowed, reply.error
    assert len(ctl.move_calls()) == int(allowed)


# ----------------------------------------------------------------------------- controller errors


@pytest.mark.parametrize(
    ("mode", "expect"),
    [
        ("protective_stop", "did not complete the move (the robot is in a protective stop"),
        ("returns_false", "no fault visible"),
        ("raises", "ur-rtde raised RuntimeError: RTDE control script is not running!"),
        ("stops_short", "the robot stopped"),
    ],
)
def test_a_move_that_fails_on_the_controller_is_reported_clearly(ctl, mode, expect):
    stage, _ = robot(ctl)
    ctl.next_move_fails = mode
    reply = stage.on_request("move", move_l("f", nudged(home_T(ctl), dx=0.01)))
    assert not reply.ok and expect in reply.error, reply.error
    assert len(ctl.move_calls()) == 1
    again = stage.on_request("move", move_l("f", nudged(home_T(ctl), dx=0.01)))
    assert again.duplicate and len(ctl.move_calls()) == 1  # an id that failed mid-motion is not retried


def test_stop_decelerates_the_joints_and_reports_the_state(ctl):
    stage, _ = robot(ctl)
    reply = stage.on_request("move", RobotCommand(command_id="s", kind="stop"))
    assert reply.ok and ("stopJ", (2.0, False)) in ctl.calls and ctl.move_calls() == []


# ----------------------------------------------------------------------------- connection and SDK


def test_unreachable_controller_error_names_the_ip_and_what_to_check(ctl):
    ctl.receive_connect_error = RuntimeError("connect: Connection refused")
    with pytest.raises(URConnectionError) as err:
        robot(ctl)
    text = str(err.value)
    assert IP in text and f"ping {IP}" in text and "Connection refused" in text and "remote control" in text


def test_control_refused_without_remote_control_says_how_to_enable_it(ctl):
    ctl.control_connect_error = RuntimeError("ur_rtde: Please enable remote control on the robot!")
    with pytest.raises(URConnectionError, match=r"not in remote control.*Remote Control.*control: false"):
        robot(ctl)
    assert ("receive.disconnect", ()) in ctl.calls  # the receive link opened first is released


def test_missing_sdk_names_the_extra_and_the_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "rtde_receive", None)  # import fails as if not installed
    stage, _ = make_stage(URRobot, PARAMS)
    with pytest.raises(MissingSDKError, match=r"'ur_robot'.*'rtde_receive'.*ur-rtde.*pip install 'vgr\[ur\]'"):
        stage.setup()


def test_halt_decelerates_the_joints_at_once_and_only_with_control(ctl):
    stage, _ = robot(ctl)
    stage.halt()
    assert ("stopJ", (2.0, False)) in ctl.calls and ctl.move_calls() == []
    ctl.calls.clear()
    stage, _ = robot(ctl, control=False)
    stage.halt()  # read-only: there is no control interface to stop with, and nothing it commanded
    assert not [c for c in ctl.calls if c[0] == "stopJ"]


def test_teardown_stops_the_script_and_disconnects_once(ctl):
    stage, _ = robot(ctl)
    stage.teardown()
    stage.teardown()
    assert [c[0] for c in ctl.calls].count("stopScript") == 1
    assert ("control.disconnect", ()) in ctl.calls and ("receive.disconnect", ()) in ctl.calls


# ----------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    ("bad", "expect"),
    [
        ({"move_l_speed_m_s": 0.5}, "exceeds move_l_speed_max_m_s"),
        ({"move_l_speed_max_m_s": 1.5}, "less than or equal to 1"),
        ({"move_j_speed_max_rad_s": 4.0}, "less than or equal to 3.14"),
        ({"workspace_min_m": (0, 0, 0), "workspace_max_m": (1, 0, 1)}, "must be below max"),
        ({"joint_min_deg": (0,) * 6, "joint_max_deg": (0,) * 6}, "joint_min_deg must be below"),
        ({"workspace_min_m": None}, "workspace_min_m"),
    ],
)
def test_parameters_have_hard_maxima_and_must_be_consistent(bad, expect):
    with pytest.raises(ValidationError, match=expect):
        URRobot.Params(**{**PARAMS, **bad})


def test_workspace_is_required_and_every_parameter_is_described():
    with pytest.raises(ValidationError, match="workspace_max_m"):
        URRobot.Params(ip=IP, workspace_min_m=(0, 0, 0))
    d = URRobot.describe()
    assert d["params"]["ip"]["required"] and d["params"]["workspace_min_m"]["required"]
    assert all(v["description"] for v in d["params"].values())


def test_an_sdk_error_during_the_checks_is_answered_and_the_id_is_spent(ctl, monkeypatch):
    stage, _ = robot(ctl)

    def lost(q):
        raise RuntimeError("RTDE control connection lost")

    monkeypatch.setattr(stage.driver, "forward_kinematics", lost)
    cmd = RobotCommand(command_id="q", kind="move_j", joints=ctl.q + np.radians([1, 0, 0, 0, 0, 0]))
    reply = stage.on_request("move", cmd)
    assert not reply.ok and reply.error == "move_j: RuntimeError: RTDE control connection lost"
    again = stage.on_request("move", cmd)
    assert again.duplicate and again.error == reply.error and ctl.move_calls() == []
