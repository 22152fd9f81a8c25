"""Each calibration stage inside a real Runner: results, transforms only when usable, bad input as a
failed result, degenerate data refused downstream, the action stage's ids and refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from calib_helpers import MOVEIT, MOVEIT_T_BASE_CAM_M, RECIPES, events, results, run

from plugins.calibration.handeye import simulate as he_sim
from plugins.calibration.handeye.io import write_pose_pairs_json
from plugins.util.detached import DetachedContext

pytestmark = pytest.mark.timeout(300)

HAND_EYE = """
name: he
plugins: [calib_test_stages]
seed: 5
clock: sim
stages:
  data: {{type: t_pose_pairs, params: {{path: "{path}", skip_targets: {skip}}}}}
  never: {{type: trigger, params: {{count: 0}}}}
  calibrate:
    type: handeye_calibration
    inputs: {{robot_pose: data.robot, target_pose: data.target, solve: never.out}}
    params: {{{setup}drop_unmatched: {drop}}}
"""


def hand_eye(path, setup: str | None = "eye_to_hand", skip=(), drop=True):
    """Run the stage on a pose-pair file; ``setup=None`` leaves the parameter at its default."""
    setup_param = "" if setup is None else f"setup: {setup}, "
    return run(text=HAND_EYE.format(path=path, setup=setup_param, skip=list(skip), drop=str(drop).lower()))


def test_hand_eye_stage_on_the_moveit_data_publishes_the_camera_pose_within_one_percent():
    summary, msgs = hand_eye(MOVEIT)
    assert summary.ok, summary.stop_reason
    (res,) = results(msgs)
    assert res.usable and res.kind == "hand_eye"
    t = res.estimate["T_base_cam"][:3, 3]
    assert np.all(np.abs(t - MOVEIT_T_BASE_CAM_M) <= 0.01 * np.abs(MOVEIT_T_BASE_CAM_M))
    (msg,) = msgs[("calibrate", "result")]
    assert msg.verdict == res.verdict and set(msg.transforms) == {"T_base_cam", "T_tcp_target"}
    assert msg.stamp_ns == 50 * 1_000_000_000  # the newest sample's stamp: replays reproduce it
    tfs = msgs[("calibrate", "transform")]
    assert [(t.frame_id, t.child_frame_id) for t in tfs] == [("base", "camera_calibrated"), ("tcp", "target")]
    assert np.allclose(tfs[0].T, res.estimate["T_base_cam"])


def test_the_stage_finds_the_set_up_from_the_data_by_default():
    """MoveIt's pairs are eye to hand; the stage's default (auto) must say so and publish that tree."""
    summary, msgs = hand_eye(MOVEIT, setup=None)
    assert summary.ok, summary.stop_reason
    (res,) = results(msgs)
    assert res.usable and "T_base_cam" in res.estimate and res.metrics["setup_found_from_data"] == 1.0
    assert np.allclose(res.estimate["T_base_cam"][:3, 3], MOVEIT_T_BASE_CAM_M, rtol=0.01)
    tfs = msgs[("calibrate", "transform")]
    assert [(t.frame_id, t.child_frame_id) for t in tfs] == [("base", "camera_calibrated"), ("tcp", "target")]


def test_missed_detections_are_dropped_with_a_warning_or_fail_the_calibration():
    summary, msgs = hand_eye(MOVEIT, skip=(3, 17))
    (res,) = results(msgs)
    assert res.usable and res.metrics["n_samples"] == 48
    (note,) = events(summary, "calibration_input")
    assert "2 of 50 robot poses have no target poses within 0.05 s" in note.message and "dropped" in note.message
    summary, msgs = hand_eye(MOVEIT, skip=(3,), drop=False)
    (res,) = results(msgs)
    assert res.verdict == "failed" and res.reasons[0].startswith("bad input: 1 of 50 robot poses")
    assert msgs[("calibrate", "transform")] == []


def test_degenerate_hand_eye_data_never_goes_downstream_as_a_transform(tmp_path):
    scene = he_sim.viewing_scene(np.random.default_rng(30), 12, "eye_in_hand", max_tilt_deg=0.0, max_roll_deg=60.0)
    path = tmp_path / "rolls.json"
    write_pose_pairs_json(path, scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand")
    summary, msgs = hand_eye(path, setup="eye_in_hand")
    assert summary.ok  # a refused calibration is a result, not a crash
    (res,) = results(msgs)
    assert res.verdict == "degenerate" and res.advice
    assert msgs[("calibrate", "transform")] == []
    assert msgs[("calibrate", "result")][0].transforms == {}
    (warn,) = events(summary, "calibration_unusable")
    assert "degenerate, no transform published" in warn.message and warn.details["advice"]


def test_vive_with_one_fixture_orientation_is_degenerate_and_the_converter_refuses_it():
    summary, msgs = run(RECIPES / "calibrate_vive_desk_sim.yaml", ["poses.grid.orientations_rpy_deg=[[180, 0, 0]]"])
    (res,) = results(msgs)
    assert res.verdict == "degenerate" and "lever" in " ".join(res.reasons)
    assert msgs[("calibrate", "transform")] == []
    (alarm,) = events(summary, "calibration_refused")
    assert alarm.level == "alarm" and "degenerate" in alarm.message
    assert msgs[("desktop", "pose")] == [] and msgs[("desktop", "representations")] == []
    assert "4 tracker pose(s) not converted" in events(summary, "not_converted")[0].message


VIVE_FROM_FILE = """
name: vive_live
seed: 9
clock: sim
stages:
  calibration: {{type: calibration_file, params: {{path: "{path}"}}}}
  vive:
    type: sim_tracker
    params:
      T_world_lighthouse: {{xyz_m: [1.2, -0.8, 2.1], rpy_deg: [-90, 25, 1.5]}}
      T_tcp_tracker: {{xyz_m: [0.02, 0.03, -0.14], rpy_deg: [10, -15, 35]}}
      T_world_tcp: {{xyz_m: [-0.5, 0.0, 0.1], rpy_deg: [170, 10, 20]}}
      position_sigma_m: 3.0e-4
      rotation_sigma_deg: 0.02
      stream_hz: 20
      duration_s: 1.0
  desktop:
    type: vive_to_desktop
    inputs: {{tracker_pose: vive.pose, calibration: calibration.calibration}}
"""


def test_vive_to_desktop_with_a_saved_calibration_tracks_the_tcp_in_the_desk_frame(tmp_path):
    _, msgs = run(RECIPES / "calibrate_vive_desk_sim.yaml")
    path = tmp_path / "result.json"
    path.write_text(msgs[("calibrate", "result")][0].result_json)
    summary, live = run(text=VIVE_FROM_FILE.format(path=path))
    assert summary.ok, summary.stop_reason
    poses = live[("desktop", "pose")]
    assert len(poses) == 20  # a reading that arrived before the calibration waited, none lost
    from engine.transforms import inv
    from plugins.params import PoseSpec

    T_desk_tcp = (
        inv(PoseSpec(xyz_m=(-0.40, 0.05, 0.05), rpy_deg=(0, 0, 180)).T())
        @ PoseSpec(xyz_m=(-0.5, 0.0, 0.1), rpy_deg=(170, 10, 20)).T()
    )
    reps = [json.loads(bytes(r.data)) for r in live[("desktop", "representations")]]
    for p, doc in zip(poses, reps, strict=True):  # within the propagated uncertainty (calibration + jitter)
        err = p.T[:3, 3] - T_desk_tcp[:3, 3]
        assert np.all(np.abs(err) < 4 * np.asarray(doc["si"]["position_std_m"])), (err, doc["si"]["position_std_m"])
        assert np.linalg.norm(err) < 3e-3
    assert max(reps[0]["si"]["position_std_m"]) < 1e-3


def test_a_degenerate_saved_calibration_is_refused(tmp_path):
    _, msgs = run(RECIPES / "calibrate_vive_desk_sim.yaml", ["poses.grid.orientations_rpy_deg=[[180, 0, 0]]"])
    path = tmp_path / "result.json"
    path.write_text(msgs[("calibrate", "result")][0].result_json)
    summary, live = run(text=VIVE_FROM_FILE.format(path=path))
    assert events(summary, "calibration_refused") and live[("desktop", "pose")] == []


def test_tcp_rotations_about_one_axis_are_degenerate_and_publish_no_transform():
    rot = "poses.pattern.rotations_rpy_deg=[[0, 0, 30], [0, 0, -30], [0, 0, 60], [0, 0, -60]]"
    _, msgs = run(RECIPES / "calibrate_tcp_sim.yaml", [rot])
    (res,) = results(msgs)
    assert res.verdict == "degenerate" and any("second" in a for a in res.advice)
    assert msgs[("calibrate", "transform")] == []


def test_kinematic_stage_too_few_samples_is_bad_input_and_a_frozen_wrist_is_degenerate():
    summary, msgs = run(RECIPES / "calibrate_kinematics_sim.yaml", ["vars.n_poses=8"])
    (res,) = results(msgs)
    assert res.verdict == "failed" and "bad input: 8 samples" in res.reasons[0] and "at least 10" in res.reasons[0]
    assert msgs[("calibrate", "transform")] == [] and events(summary, "calibration_unusable")
    frozen = "poses.random_joints.ranges_deg=[[-180,180],[-180,180],[-180,180],[-180,180],[0,0],[0,0]]"
    _, msgs = run(RECIPES / "calibrate_kinematics_sim.yaml", ["vars.n_poses=40", frozen])
    (res,) = results(msgs)
    assert res.verdict == "degenerate" and "do not excite" in " ".join(res.reasons)
    assert msgs[("calibrate", "transform")] == []


def test_calibration_poses_ids_are_deterministic_and_a_refusal_stops_the_sequence():
    summary, msgs = run(RECIPES / "calibrate_tcp_sim.yaml")
    ids = [c.command_id for c in msgs[("poses", "_svc/robot")]]
    assert ids == [f"poses-1-{k}" for k in range(17)]
    assert len(msgs[("poses", "done")]) == 1 and msgs[("poses", "done")][0].args["samples"] == 17
    # the 8th target (a pure translation) is out of reach: alarm, nothing after it, no `done`
    far = "poses.pattern.translations_m=[[0.06, 0, 0], [-0.06, 0, 0], [0, 0.06, 0], [0, -0.06, 0], [0, 0, 0.06], [0, 0, -0.06], [2.0, 0, 0]]"
    summary, msgs = run(RECIPES / "calibrate_tcp_sim.yaml", [far])
    (alarm,) = events(summary, "robot_refused")
    assert alarm.level == "alarm" and "pose 7" in alarm.message and "stopped" in alarm.message
    assert len(msgs[("poses", "_svc/robot")]) == 8 and len(msgs[("poses", "point")]) == 7
    assert msgs[("poses", "done")] == []
    (res,) = results(msgs)  # solved at the end of the run from the 7 samples taken: not enough rotation
    assert not res.usable and msgs[("calibrate", "transform")] == []


def test_a_solve_that_overtakes_its_samples_waits_for_them():
    from engine.messages import PoseStamped, Request
    from plugins.calibration.handeye.io import load_pose_pairs
    from plugins.calibration.stages.hand_eye import HandEyeCalibration

    s = load_pose_pairs(MOVEIT)
    ctx = DetachedContext("calibrate", seed=5)
    stage = HandEyeCalibration(ctx, HandEyeCalibration.Params(setup="eye_to_hand"))
    stage.setup()
    stage.on_message("solve", Request(command="solve", args={"total_samples": 50}, seq=1))  # arrives first
    for k in range(50):
        stamp = (k + 1) * 1_000_000_000
        stage.on_message("robot_pose", PoseStamped(T=s.T_base_tcp[k], frame_id="base", stamp_ns=stamp))
        assert not [p for p, _ in ctx.published if p == "result"]  # nothing solved from a partial set
        stage.on_message("target_pose", PoseStamped(T=s.T_cam_target[k], frame_id="camera", stamp_ns=stamp))
    (result,) = [m for p, m in ctx.published if p == "result"]
    assert result.verdict == "warning" and json.loads(result.result_json)["metrics"]["n_samples"] == 50
    stage.finish()  # nothing new since: no second result
    assert len([p for p, _ in ctx.published if p == "result"]) == 1


class FakeRobotContext(DetachedContext):
    """A detached context whose robot executes each command id once (a repeat answers
    ``duplicate``) and whose point instrument answers at a fixed stamp."""

    def __init__(self) -> None:
        super().__init__("poses")
        self.seen: set[str] = set()

    def call(self, client, request, timeout_s=10.0):
        import numpy as np

        from engine.messages import PoseStamped, RobotReply

        if client == "robot":
            dup = request.command_id in self.seen
            self.seen.add(request.command_id)
            return RobotReply(command_id=request.command_id, ok=True, T=np.eye(4), joints=np.zeros(6), duplicate=dup)
        return PoseStamped(T=np.eye(4), frame_id="tracker", stamp_ns=123)


def test_a_repeated_trigger_moves_and_measures_nothing():
    from engine.messages import Request
    from plugins.actions.stages.calibration_poses import CalibrationPoses

    ctx = FakeRobotContext()
    stage = CalibrationPoses(ctx, CalibrationPoses.Params(joints_deg=((0,) * 6, (10,) * 6), sensors=("point",)))
    stage.setup()
    stage.on_message("trigger", Request(command="start", seq=1))
    stage.on_message("trigger", Request(command="start", seq=1))  # the same trigger again (a restart, a replay)
    ports = [p for p, _ in ctx.published]
    assert ports.count("point") == 2 and ports.count("done") == 1
    assert [(e.level, e.code, e.message) for e in ctx.events] == [
        ("warning", "duplicate_trigger", "command poses-1-0 was already executed; sequence skipped")
    ]
    stage.on_message("trigger", Request(command="start", seq=2))  # a new trigger: new ids, moves again
    done = [m for p, m in ctx.published if p == "done"]
    assert [d.args["total_samples"] for d in done] == [2, 4]
