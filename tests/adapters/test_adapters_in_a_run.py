"""The adapters inside real vgr runs (Runner, zenoh bus, typed ports, services, recording, replay).

The SDKs are faked at the adapter boundary (fake rtde_*/openvr/pyrealsense2 modules); everything
from the stage inwards is the engine as it runs on a cell. The recipes use the adapters exactly
where the simulated twins would be, through the same action stages (capture_at_pose).
"""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest
from adapter_fixtures import SEEN
from adapter_recipes import SIM_PHOTO, adapter_header, capture_at_pose, ur_robot
from fake_openvr import FakeDevice, FakeOpenVR
from fake_openvr import install as install_openvr
from fake_realsense import FakeCamera, Intrinsics
from fake_realsense import install as install_realsense
from fake_ur_rtde import IP, WORKSPACE, FakeURController, matrix_yaml, photo_pose
from fake_ur_rtde import install as install_ur
from recipe_helpers import graph_from, stages
from shared_data import SHARED

from engine import transforms as tf
from engine.recording.recorder import Recorder
from engine.recording.replay import replay
from engine.run.runner import Runner

pytestmark = pytest.mark.timeout(180)

PCL = SHARED / "pcl"


def run(text: str, **kw):
    graph = graph_from(textwrap.dedent(text))
    return Runner(graph, **kw).run()


def ur_files(rid: str, photo: str, robot_params: str = WORKSPACE) -> str:
    """The UR robot and the file camera: 3 captures at *photo* (a YAML matrix); the clouds and poses
    captured and the robot's TCP poses and joint states collected."""
    return adapter_header("ur_files", rid) + stages(
        ur_robot(robot_params),
        f"""
        camera:
          type: file_camera
          params: {{folder: {PCL}, pattern: "*.pcd"}}
        """,
        capture_at_pose(photo, count=3),
        """
        clouds: {type: ta_collect_cloud, inputs: {in: capture.cloud}}
        poses: {type: ta_collect_pose, inputs: {in: capture.pose}}
        tcp: {type: ta_collect_pose, inputs: {in: robot.tcp_pose}}
        joints: {type: ta_collect_joints, inputs: {in: robot.joint_state}}
        """,
    )


def test_capture_at_pose_with_the_ur_adapter_and_the_file_camera(monkeypatch):
    ctl = FakeURController()
    install_ur(monkeypatch, ctl)
    T_photo = photo_pose(ctl)
    s = run(ur_files("adp-ur1", matrix_yaml(T_photo)))
    assert s.ok, s.stop_reason
    seen = SEEN["adp-ur1"]
    assert [len(c.points) for c in seen["clouds"]] == [397, 361, 13704]
    assert all(c.frame_id == "camera" for c in seen["clouds"])
    # one joint move per trigger (ids capture-1..3), each to joints whose TCP is the photo pose (the
    # controller's IK, checked against the limits first): the first moves 10 mm
    moves = ctl.move_calls()
    assert [m[0] for m in moves] == ["moveJ"] * 3
    for m in moves:
        assert tf.pose_error(ctl.model.fk(np.asarray(m[1][0]), frame="base"), T_photo)[0] < 1e-8
    assert len(seen["poses"]) == 3  # one pose per capture, published with its cloud
    for p in seen["poses"]:
        assert p.frame_id == "base" and tf.pose_error(p.T, T_photo)[0] < 1e-6
    assert len(seen["tcp"]) == 4 and len(seen["joints"]) == 4  # at set-up and after each command
    assert tf.pose_error(seen["tcp"][0].T, photo_pose(FakeURController(), 0.0))[0] < 1e-9
    assert ("stopScript", ()) in ctl.calls  # teardown released the controller


def test_a_second_run_with_the_same_command_journal_does_not_take_old_ids_for_moves(monkeypatch, tmp_path):
    """Command ids restart with every run; the UR journal remembers them across runs. A second run on
    the same journal gets 'already handled' replies: it must alarm and capture nothing, not carry on
    as if the robot had moved to the photo pose."""
    journal = tmp_path / "ur.jsonl"
    robot_params = WORKSPACE + f", command_journal: {journal}"
    for rid in ("adp-j1", "adp-j2"):
        ctl = FakeURController()
        install_ur(monkeypatch, ctl)
        s = run(ur_files(rid, matrix_yaml(photo_pose(ctl)), robot_params))
        moves = ctl.move_calls()
    assert len(SEEN["adp-j1"]["clouds"]) == 3  # the first run moved and captured
    assert moves == [] and not SEEN["adp-j2"].get("clouds")  # the second moved nothing, captured nothing
    assert [e.code for e in s.events if e.level == "alarm"] == ["duplicate_command"] * 3


def robot_script(rid: str) -> str:
    """The UR robot driven by ta_robot_script: a command id sent twice, a step too far, a move too
    fast and a joint move."""
    return adapter_header("ur_script", rid) + stages(
        ur_robot(),
        """
        start: {type: trigger, params: {count: 1}}
        script:
          type: ta_robot_script
          inputs: {trigger: start.out}
          uses: {robot: robot.move, state: robot.state}
          params:
            steps:
              - {id: a, offset_m: [0.01, 0, 0]}
              - {id: a, offset_m: [0.02, 0, 0]}
              - {id: far, offset_m: [0.2, 0, 0]}
              - {id: fast, offset_m: [0.01, 0, 0], speed: 5.0}
              - {id: b, offset_m: [0.0, 0.01, 0], kind: move_j}
        """,
    )


def test_robot_contract_over_the_bus_idempotent_ids_and_refusals(monkeypatch):
    ctl = FakeURController()
    install_ur(monkeypatch, ctl)
    s = run(robot_script("adp-ur2"))
    assert s.ok, s.stop_reason
    rows = SEEN["adp-ur2"]["script"]
    assert rows[0][:2] == ("state", True)
    (a1, a2, far, fast, b) = rows[1:]
    assert a1[:3] == ("a", True, False) and a2[:3] == ("a", True, True)  # the repeat is a duplicate
    np.testing.assert_array_equal(a1[4], a2[4])  # ... with the first reply's pose
    assert far[:2] == ("far", False) and "step limit" in far[3]
    assert fast[:2] == ("fast", False) and "speed 5 m/s exceeds" in fast[3]
    assert b[:3] == ("b", True, False)
    assert [m[0] for m in ctl.move_calls()] == ["moveL", "moveJ"]
    refusals = [e for e in s.events if e.code == "robot_refused"]
    assert {e.details["command_id"] for e in refusals} == {"far", "fast"}


def test_an_unreachable_robot_fails_the_run_with_the_ip_and_what_to_check(monkeypatch):
    ctl = FakeURController(receive_connect_error=RuntimeError("connect: No route to host"))
    install_ur(monkeypatch, ctl)
    s = run(robot_script("adp-ur3"))
    assert not s.ok
    text = s.stop_reason + " ".join(e.message + e.traceback for e in s.events)
    assert f"cannot connect to the UR controller at {IP}" in text and f"ping {IP}" in text


def test_a_missing_sdk_fails_the_run_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rtde_receive", None)
    s = run(robot_script("adp-ur4"))
    assert not s.ok
    text = s.stop_reason + " ".join(e.message + e.traceback for e in s.events)
    assert "pip install 'vgr[ur]'" in text


TRACKER = adapter_header("tracker", "adp-vive") + stages("""
  tracker:
    type: vive_tracker
    params: {serial: LHR-TRACK01, stream_hz: 10, duration_s: 1.0}
  start: {type: trigger, params: {count: 2}}
  sampler:
    type: ta_tracker_sampler
    inputs: {trigger: start.out}
    uses: {tracker: tracker.sample}
  stream: {type: ta_collect_tracker, inputs: {in: tracker.pose}}
""")


def test_vive_tracker_streams_and_samples_in_a_run(monkeypatch):
    T = tf.T_from_rotvec([0.1, 0.2, -0.3], [0.4, 1.1, -1.5])
    state = FakeOpenVR(devices={3: FakeDevice("LHR-TRACK01", T=T), 0: FakeDevice("HMD", device_class=1)})
    install_openvr(monkeypatch, state)
    s = run(TRACKER)
    assert s.ok, s.stop_reason
    stream, samples = SEEN["adp-vive"]["stream"], SEEN["adp-vive"]["sampler"]
    assert len(stream) == 10 and len(samples) == 2
    for msg in [*stream, *samples]:
        assert msg.valid and msg.serial == "LHR-TRACK01" and msg.frame_id == "lighthouse"
        assert tf.pose_error(msg.T, T)[0] < 1e-6 and tf.pose_error(msg.T, T)[1] < 1e-6
    assert np.all(np.diff([m.stamp_ns for m in stream]) == 100_000_000)
    assert state.shutdowns == 1 and set(state.universes) == {2}


SIM_ROBOT_REALSENSE = adapter_header("sim_rs", "adp-rs") + stages(
    """
    robot: {type: sim_robot, params: {model: ur5e}}
    camera:
      type: realsense_camera
      params: {width: 80, height: 60, warmup_frames: 2}
    """,
    capture_at_pose(SIM_PHOTO, count=2),
    "clouds: {type: ta_collect_cloud, inputs: {in: capture.cloud}}",
)


def test_realsense_camera_in_place_of_the_sim_camera(monkeypatch):
    z16 = np.full((60, 80), 600, np.uint16)
    z16[:, :10] = 0
    farther = np.where(z16 > 0, z16 + 100, 0).astype(np.uint16)
    cam = FakeCamera(frames=[z16, farther], intrinsics=Intrinsics(80, 60, 70.0, 70.0, 39.5, 29.5))
    install_realsense(monkeypatch, cam)
    s = run(SIM_ROBOT_REALSENSE)
    assert s.ok, s.stop_reason
    clouds = SEEN["adp-rs"]["clouds"]
    assert [len(c.points) for c in clouds] == [70 * 60, 70 * 60]
    # warm-up took frames 0, 1; each capture drops the waiting set (0) and takes the next (1: 0.7 m)
    np.testing.assert_allclose([c.points[0, 2] for c in clouds], [0.7, 0.7], rtol=1e-6)
    assert cam.stopped == 1


def test_a_recording_of_the_adapters_replays_without_any_sdk(monkeypatch, tmp_path):
    ctl = FakeURController()
    install_ur(monkeypatch, ctl)
    graph = graph_from(ur_files("adp-rec", matrix_yaml(photo_pose(ctl))))
    path = tmp_path / "cell.mcap"
    rec = Recorder(path, graph.recipe.record, graph.loaded, ["builtin", "adapter_fixtures"])
    assert Runner(graph, observers=[rec]).run().ok
    moves_recorded = len(ctl.move_calls())
    for module in ("rtde_receive", "rtde_control"):
        monkeypatch.setitem(sys.modules, module, None)  # as on a CI machine without ur-rtde
    report, _, _ = replay(path)
    assert report.ok and not report.failures, report.failures
    assert "capture" in report.rerun and "robot" not in report.rerun and "camera" not in report.rerun
    assert all(v.verdict == "identical" for v in (*report.streams, *report.requests))
    assert len(ctl.move_calls()) == moves_recorded  # replay commanded nothing
