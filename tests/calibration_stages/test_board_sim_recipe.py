"""recipes/calibrate_handeye_board_sim.yaml: the simulated camera renders a board fixed in the cell,
handeye_board_calibration recovers the camera mount within its reported uncertainty, the evaluator
reports its error against the truth; the run replays identically, and `vgr calibrate handeye RUN.mcap
--board SPEC` on its recording gives the same result. The board_pose -> handeye_calibration chain
runs too (its board poses, its result)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from calib_helpers import RECIPES, events, mahalanobis2, results, run
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2
from test_sim_recipes import assert_replays_identically, decoupled_error, pose, recorded_run, stage_params
from usable_verdicts import USABLE

from engine.cli.main import main
from engine.messages import PoseWithCovarianceStamped
from engine.transforms import inv
from plugins.calibration.boards.detect import detect_board
from plugins.camera.board_spec import parse_board
from plugins.camera.pinhole import CameraModel

pytestmark = pytest.mark.timeout(300)

RECIPE = RECIPES / "calibrate_handeye_board_sim.yaml"
BOARD = "chessboard:9x6:20mm"
board_run = recorded_run("calibrate_handeye_board_sim.yaml")


def truth() -> tuple[np.ndarray, np.ndarray]:
    cam = stage_params(RECIPE, "camera")
    return pose(cam["mount"]["pose"]), pose(cam["board"]["pose"])


def test_the_recipe_recovers_the_camera_mount_within_its_reported_uncertainty(board_run):
    summary, msgs, _ = board_run
    assert summary.ok, summary.stop_reason
    (res,) = results(msgs)
    assert res.usable, res.reasons
    assert "reprojection refinement" in res.method and res.metrics["n_views"] == 12
    T_tcp_cam, T_base_board = truth()
    err_x = decoupled_error(T_tcp_cam, res.estimate["T_tcp_cam"])
    sd_x = np.sqrt(np.diag(res.covariance)[:6])
    assert mahalanobis2(err_x, res.covariance[:6, :6]) < chi2.ppf(0.99, 6)
    assert np.all(np.abs(err_x) < 3 * sd_x), (err_x, sd_x)
    assert np.linalg.norm(err_x[:3]) < 5e-4 and np.degrees(np.linalg.norm(err_x[3:])) < 0.1
    err_y = decoupled_error(T_base_board, res.estimate["T_base_target"])
    assert np.linalg.norm(err_y[:3]) < 5e-4 and np.degrees(np.linalg.norm(err_y[3:])) < 0.1
    tfs = msgs[("calibrate", "transform")]
    assert [(t.frame_id, t.child_frame_id) for t in tfs] == [("tcp", "camera_calibrated"), ("base", "target")]
    (ev,) = [e for e in summary.events if e.level == "result" and e.code == "hand_eye_result"]
    assert ev.message.startswith(f"hand-eye calibration: verdict {res.verdict}")
    (truth_ev,) = events(summary, "calibration_evaluation")
    err = truth_ev.details["errors"]["T_tcp_cam"]
    assert err["error_mm"] == pytest.approx(np.linalg.norm(err_x[:3]) * 1e3, abs=1e-6)
    assert not any(
        "outlier" in r for r in res.reasons
    )  # (the pose solver's down-weighted pair is judged by its corners)


def test_the_stage_and_the_cli_on_its_recording_give_the_same_result(board_run, tmp_path, capsys):
    """One pipeline: the recipe's result and `vgr calibrate handeye RUN.mcap --board` agree to the last
    figure -- estimate, covariance, verdict."""
    _, msgs, path = board_run
    (res,) = results(msgs)
    out = tmp_path / "cli.json"
    code = main(["calibrate", "handeye", str(path), "--board", BOARD, "--json", str(out)])
    capsys.readouterr()
    cli = json.loads(out.read_text())
    assert (code, cli["verdict"]) in USABLE
    np.testing.assert_allclose(np.asarray(cli["estimate"]["T_tcp_cam"]), res.estimate["T_tcp_cam"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(cli["covariance"]), res.covariance, rtol=1e-9, atol=1e-18)
    assert (cli["verdict"], cli["reasons"]) == (res.verdict, res.reasons)


def test_the_board_pose_chain_gives_board_poses_with_covariances_and_a_result(tmp_path):
    """board_pose -> handeye_calibration (the chain for target poses with covariances) on the same cell."""
    doc = yaml.safe_load(RECIPE.read_text())
    doc["stages"]["board"] = {
        "type": "board_pose",
        "inputs": {"image": "camera.image", "camera_info": "camera.image_info"},
        "params": {"board": BOARD},
    }
    doc["stages"]["calibrate"] = {
        "type": "handeye_calibration",
        "inputs": {"robot_pose": "poses.tcp_pose", "target_pose": "board.pose", "solve": "poses.done"},
        "params": {"setup": "eye_in_hand"},
    }
    recipe = tmp_path / "board_pose_chain.yaml"
    recipe.write_text(yaml.safe_dump(doc))
    summary, msgs = run(recipe)
    assert summary.ok, summary.stop_reason
    poses = msgs[("board", "pose")]
    assert len(poses) == 12 and all(isinstance(p, PoseWithCovarianceStamped) for p in poses)
    assert all(np.all(np.linalg.eigvalsh(p.covariance) > 0) for p in poses)
    (res,) = results(msgs)
    assert res.usable, res.reasons
    err_x = decoupled_error(truth()[0], res.estimate["T_tcp_cam"])
    assert np.linalg.norm(err_x[:3]) < 5e-4 and np.degrees(np.linalg.norm(err_x[3:])) < 0.1
    assert events(summary, "calibration_evaluation")  # the evaluator ends with the run (it hung once)


def test_the_simulated_image_shows_the_board_where_the_truth_puts_it(board_run):
    """The intensity image: the board's corners are detected within 0.3 px of their true projection
    through the lens model the camera publishes (distortion included)."""
    _, msgs, _ = board_run
    board = parse_board(BOARD)
    image, info, truth_tf = msgs[("camera", "image")][3], msgs[("camera", "image_info")][3], None
    camera = CameraModel.from_camera_info(info)
    assert camera.D[0] != 0 and image.encoding == "mono8" and image.stamp_ns == info.stamp_ns
    for ft in msgs[("camera", "truth/part_poses")]:
        if ft.stamp_ns == image.stamp_ns:
            truth_tf = {t.child_frame_id: t.T for t in ft.transforms}
    assert truth_tf is not None
    T_cam_board = inv(truth_tf["truth/camera"]) @ truth_tf["truth/board"]
    det = detect_board(image.data, board)
    err = det.image_points - camera.project(T_cam_board, det.object_points)
    assert np.max(np.linalg.norm(err, axis=1)) < 0.3, np.abs(err).max()
    assert any(len(c.points) > 1000 for c in msgs[("poses", "cloud")])  # the board's plate in the depth


def test_the_run_replays_identically_and_the_cli_runs_the_images_pipeline_on_it(board_run, tmp_path, capsys):
    path = board_run[2]
    assert_replays_identically(path)
    out = tmp_path / "r.json"
    code = main(["calibrate", "handeye", str(path), "--board", BOARD, "--json", str(out), "--no-samples"])
    text = capsys.readouterr().out
    assert "12 images on /camera/image paired with robot poses" in text and "board found in 12 of 12" in text
    cli = json.loads(out.read_text())
    assert (code, cli["verdict"]) in USABLE and "reprojection refinement" in cli["method"]
    T_tcp_cam, _ = truth()
    err = decoupled_error(T_tcp_cam, np.asarray(cli["estimate"]["T_tcp_cam"]))
    assert np.linalg.norm(err[:3]) < 5e-4 and np.degrees(np.linalg.norm(err[3:])) < 0.1
    assert cli["metrics"]["n_views"] == 12 and cli["metrics"]["rms_px"] < 0.2


def test_the_cli_refuses_a_recording_without_the_image_topic_or_a_board_with_a_plain_file(board_run, tmp_path, capsys):
    _, _, path = board_run
    assert main(["calibrate", "handeye", str(path), "--board", BOARD, "--image-topic", "/nope"]) == 2
    assert "no topic '/nope'" in capsys.readouterr().err
    plain = tmp_path / "pairs.json"
    plain.write_text("{}")
    assert main(["calibrate", "handeye", str(plain), "--board", BOARD]) == 2
    assert "must be .mcap" in capsys.readouterr().err


def test_a_board_not_in_the_images_fails_and_publishes_no_transform():
    # not the board in the cell (a smaller chessboard could match a part of it: a ChArUco board has markers)
    summary, msgs = run(RECIPE, ["calibrate.board=charuco:9x6:20mm:15mm:DICT_4X4_50"])
    dropped = [e for e in events(summary, "calibration_input") if "its robot pose is dropped" in e.message]
    assert len(dropped) == 12
    (res,) = results(msgs)
    assert res.verdict == "failed" and any("found in 0 image(s)" in r for r in res.reasons), res.reasons
    assert msgs[("calibrate", "transform")] == []


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 8), min_size=1, max_size=3).filter(lambda s: s != [6, 6]))
def test_a_pose_covariance_that_is_not_6x6_is_refused(shape):
    with pytest.raises(ValueError, match="6x6"):
        PoseWithCovarianceStamped(covariance=np.zeros(shape))
