"""Hand-eye from images on real data: RWHE-Calib's rendered CS_synthetic_1 (ground truth known) and
the real kuka_2 images (judged by consistency), through the library and ``vgr calibrate handeye
--images``. Detection runs once per set (module fixtures); the shared data must be there."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import jsonschema
import numpy as np
import pytest
from shared_data import SHARED

from engine.transforms import angle_between, pose_delta, retract
from plugins.calibration.boards.board_pose import AmbiguousBoardError
from plugins.calibration.boards.detect import detect_board, detect_images
from plugins.calibration.boards.handeye_images import ImagePoseMismatchError, calibrate_handeye_images, pair_views
from plugins.calibration.boards.intrinsics import calibrate_intrinsics
from plugins.calibration.boards.reprojection import view_residuals
from plugins.calibration.boards.robot_poses import load_robot_poses
from plugins.calibration.cli import main as calibrate_main
from plugins.camera.board_spec import parse_board

ROOT = Path(__file__).resolve().parents[2]

SYNTH_DIR, KUKA_DIR = SHARED / "rwhe_synthetic1", SHARED / "rwhe_kuka2"
SYNTH, KUKA = parse_board("chessboard:10x7:200mm"), parse_board("chessboard:25x18:15mm")
# GroundTruth.txt of CS_synthetic_1 (4 decimals): hand2eye = T_tcp_cam, base2grid = T_base_grid
GT_X = np.diag([1.0, -1.0, -1.0, 1.0])
GT_BASE_GRID = np.array(
    [[-0.0448, -0.0230, 0.9987, 7.6449], [-0.9988, -0.0206, -0.0453, 1.0292], [0.0216, -0.9995, -0.0220, 3.9675],
     [0, 0, 0, 1.0]]
)  # fmt: skip
# their grid frame (OpenCV's: first inner corner, y down, z into the board) in vgr's target frame
T_GRID_TARGET = np.array([[1, 0, 0, -0.2], [0, -1, 0, 1.2], [0, 0, -1, 0], [0, 0, 0, 1.0]])


def _load(folder, board):
    files = sorted(folder.glob("im_*.png"))
    dets = detect_images(files, board)
    cal = calibrate_intrinsics(dets)
    views, M, _ = pair_views(files, dets, load_robot_poses(folder / "RobotPosesVec.txt"))
    return files, dets, cal.camera, views, M


@pytest.fixture(scope="module")
def synth():
    out = _load(SYNTH_DIR, SYNTH)
    assert len(out[3]) == 15
    return out


@pytest.fixture(scope="module")
def kuka():
    out = _load(KUKA_DIR, KUKA)
    assert len(out[3]) == 28
    return out


def test_synthetic_1_recovers_the_ground_truth(synth):
    _, _, camera, views, M = synth
    out = calibrate_handeye_images(views, M, camera, refine_intrinsics=True)
    r = out.result
    assert r.verdict == "ok", r.reasons
    X, Y = r.estimate["T_tcp_cam"], r.estimate["T_base_target"]
    Y_true = GT_BASE_GRID @ T_GRID_TARGET
    # stated bound: the truth is given to 0.1 mm / 1e-4; vgr's corner noise model is optimistic
    # (the detector's error shared by a view's corners), so its 1-sigma (0.05 mm) is not the bound
    assert np.linalg.norm(X[:3, 3] - GT_X[:3, 3]) < 1.0e-3
    assert np.degrees(angle_between(X[:3, :3], GT_X[:3, :3])) < 0.01
    assert np.linalg.norm(Y[:3, 3] - Y_true[:3, 3]) < 1.0e-3
    assert np.degrees(angle_between(Y[:3, :3], Y_true[:3, :3])) < 0.01
    # the error to the truth in the reported covariance's metric (6 dof): 28.7 with the robot and
    # corner noise estimated from the corners; 516 with the corner noise alone (the covariance before)
    e = pose_delta(X, GT_X)[0]
    assert e @ np.linalg.solve(r.covariance[:6, :6], e) < 40.0
    assert e @ np.linalg.solve(out.refinement.covariance[:6, :6], e) > 200.0
    # every view reprojects through the robot pose within 0.05 px, held out too
    assert r.metrics["rms_px"] < 0.05 and r.metrics["holdout_rms_px"] < 0.05
    assert r.metrics["holdout_rms_px"] >= r.metrics["rms_px"]


def test_refinement_in_pixels_beats_the_pose_solution(synth):
    _, _, camera, views, M = synth
    out = calibrate_handeye_images(views, M, camera, holdout=False)
    assert out.ml_result is not None and out.refinement is not None
    ml = out.ml_result.estimate
    before = view_residuals("eye_in_hand", M, ml["T_tcp_cam"], ml["T_base_target"], camera, views)
    rms_before = np.sqrt(np.mean(np.concatenate([np.sum(r**2, axis=1) for r in before])))
    assert out.refinement.rms_px < 0.9 * rms_before  # 0.124 px against 0.153 px
    # the intrinsics calibrated alone leave the hand-eye 2 mm off in depth: bounded, refining fixes it
    assert np.linalg.norm(out.refinement.X[:3, 3]) < 2.5e-3


def test_kuka_2_board_pose_spread_and_reprojection(kuka):
    _, _, camera, views, M = kuka
    out = calibrate_handeye_images(views, M, camera, holdout=False)
    r = out.result
    assert r.usable, r.reasons
    assert out.ml_result is not None
    # vgr's pose solver: the board's world pose over the 28 views (OpenCV Park/Horaud: 0.66 mm / 0.047 deg)
    assert out.ml_result.metrics["chain_spread_trans_rms_m"] < 0.75e-3
    assert np.degrees(out.ml_result.metrics["chain_spread_rot_rms_rad"]) < 0.055
    # after the pixel refinement: corners through the robot poses 1.1 px (OpenCV's best: 1.6 px)
    assert r.metrics["rms_px"] < 1.2
    ml = out.ml_result.estimate
    before = view_residuals("eye_in_hand", M, ml["T_tcp_cam"], ml["T_base_target"], camera, views)
    assert r.metrics["rms_px"] < 0.75 * np.sqrt(np.mean(np.concatenate([np.sum(b**2, axis=1) for b in before])))
    assert r.metrics["world_spread_trans_rms_m"] < 0.7e-3
    assert np.degrees(r.metrics["world_spread_rot_rms_rad"]) < 0.2
    X = r.estimate["T_tcp_cam"]
    assert np.linalg.norm(X[:3, 3] - [0.0144, -0.1079, -0.0819]) < 2e-3  # OpenCV Park's, within 2 mm
    # the robot's pose noise estimated from the corners: 0.235 mm / 0.032 deg per axis, corners 0.058 px
    assert 0.15e-3 < r.metrics["robot_sigma_trans_m"] < 0.35e-3
    assert 0.02 < np.degrees(r.metrics["robot_sigma_rot_rad"]) < 0.045
    assert r.metrics["corner_sigma_px"] < 0.1
    assert out.outlier_views == []


def test_kuka_2_with_the_robot_noise_modelled(kuka):
    # the board's world pose agrees as well as OpenCV Park's (0.047 deg) instead of 0.17 deg; the
    # corners through the robot poses fit worse (1.75 px against 1.12 px): kuka_2's robot errors are
    # not independent between poses, and the exact-robot fit absorbs part of them (module docs)
    _, _, camera, views, M = kuka
    r = calibrate_handeye_images(views, M, camera, holdout=False, model_robot_noise=True).result
    assert r.usable, r.reasons
    assert np.degrees(r.metrics["world_spread_rot_rms_rad"]) < 0.06
    assert r.metrics["world_spread_trans_rms_m"] < 0.8e-3
    assert 1.5 < r.metrics["rms_px"] < 2.0
    assert np.degrees(r.metrics["std_x_rot_rad"]) < 0.05 and r.metrics["std_x_trans_m"] < 0.5e-3


def test_a_pose_solver_that_does_not_converge_is_not_the_end(synth, monkeypatch):
    # the pose solver with the noise estimated can fail to converge on views whose robot poses are
    # exact (it does on some 14-view subsets of this set); then the declared-noise solution and the
    # closed forms start the pixel refinement instead
    import plugins.calibration.boards.handeye_images as he

    real = he.calibrate_hand_eye

    def not_converging(*args, **kwargs):
        res = real(*args, **kwargs)
        if kwargs.get("estimate_noise"):
            res.verdict = "failed"
            res.reasons.append("the maximum-likelihood refinement did not converge")
            res.estimate["T_tcp_cam"] = res.estimate["T_tcp_cam"].copy()
            res.estimate["T_tcp_cam"][:3, 3] += 0.05  # a poor start
        return res

    monkeypatch.setattr(he, "calibrate_hand_eye", not_converging)
    _, _, camera, views, M = synth
    out = he.calibrate_handeye_images(views, M, camera, refine_intrinsics=True, holdout=False)
    assert out.ml_result is not None and not out.ml_result.usable
    r = out.result
    assert r.verdict == "warning" and "the pose solver alone gave verdict failed" in r.reasons[0]
    assert r.metrics["rms_px"] < 0.05
    assert np.linalg.norm(r.estimate["T_tcp_cam"][:3, 3] - GT_X[:3, 3]) < 1.0e-3


def test_a_wrong_square_size_is_caught(synth):
    _, _, camera, views, M = synth
    small = [replace(v, object_points=v.object_points * 0.95) for v in views]  # 190 mm given, 200 mm printed
    r = calibrate_handeye_images(small, M, camera, holdout=False).result
    assert not r.usable
    assert any(s.startswith("square size? the robot moved 1.05") for s in r.reasons), r.reasons


def test_a_board_that_moved_is_flagged(synth):
    _, _, camera, views, M = synth
    moved = M.copy()
    moved[-2:] = retract(np.eye(4), [0.004, -0.003, 0.002, 0.0, 0.003, 0.002]) @ M[-2:]  # 5.4 mm, 0.21 deg
    out = calibrate_handeye_images(views, moved, camera, holdout=False)
    assert out.outlier_views == ["im_14.png", "im_15.png"]
    r = out.result
    assert r.verdict == "warning" and r.estimate["outlier_views"] == ["im_14.png", "im_15.png"]
    assert any("the board moved" in x and "im_14.png, im_15.png" in x for x in r.reasons), r.reasons
    assert r.metrics["n_views"] == 13 and r.metrics["rms_px"] < 0.2


def test_a_mirrored_view_is_left_out_and_a_mirrored_camera_refused(synth):
    _, _, camera, views, M = synth
    mirrored = [replace(detect_board(cv2.flip(cv2.imread(v.name, cv2.IMREAD_GRAYSCALE), 1), SYNTH), name=v.name)
                for v in views]  # fmt: skip
    one = [mirrored[2] if k == 2 else v for k, v in enumerate(views)]
    assert calibrate_handeye_images(one, M, camera, holdout=False).outlier_views == ["im_03.png"]
    r = calibrate_handeye_images(mirrored, M, camera, holdout=False).result
    assert r.verdict == "failed" and "the camera moved mirrored to the robot" in r.reasons[0], r.reasons


def test_an_ambiguous_board_is_refused(synth):
    _, _, camera, views, M = synth
    with pytest.raises(AmbiguousBoardError, match="looks the same turned by 180 degrees"):
        calibrate_handeye_images([replace(v, ambiguous=True) for v in views], M, camera, holdout=False)


def test_images_and_poses_of_different_counts(synth):
    files, dets, _, _, M = synth
    with pytest.raises(ImagePoseMismatchError, match=r"15 image.* but 14 robot pose"):
        pair_views(files, dets, M[:14])


def _run(capsys, *argv):
    code = calibrate_main(["handeye", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_drops_the_pose_of_an_image_without_board_or_corrupt(tmp_path, capsys):
    d = tmp_path / "imgs"
    d.mkdir()
    for f in sorted(SYNTH_DIR.glob("im_*.png")):
        shutil.copy(f, d / f.name)
    cv2.imwrite(str(d / "im_07.png"), np.full((480, 640), 128, np.uint8))  # no board, other size
    (d / "im_03.png").write_bytes((SYNTH_DIR / "im_03.png").read_bytes()[:300])  # truncated
    out_json, report = tmp_path / "he.json", tmp_path / "report"
    code, out, err = _run(
        capsys,
        "--images",
        d,
        "--poses",
        SYNTH_DIR / "RobotPosesVec.txt",
        "--board",
        "chessboard:10x7:200mm",
        "--refine-intrinsics",
        "--no-holdout",
        "--json",
        out_json,
        "--report",
        report,
    )  # fmt: skip  (per-sample lines on: the default, which crashed on image views once)
    assert code == 0, err
    assert "im_07.png" in out and "robot pose is dropped" in out
    assert "im_03.png: not a readable image (corrupt or truncated?); its robot pose is dropped" in out
    doc = json.loads(out_json.read_text())
    assert doc["metrics"]["n_views"] == 13 and "im_07.png" not in doc["estimate"]["sample_labels"]
    X = np.asarray(doc["estimate"]["T_tcp_cam"])
    assert np.linalg.norm(X[:3, 3]) < 1.5e-3
    assert doc["metrics"]["holdout_rms_px"] is None  # --no-holdout: not measured, strict JSON (no NaN)
    # the corners the result rests on, for anyone to check it with (vgr.board_detections/1)
    det = json.loads((report / "detections.json").read_text())
    jsonschema.validate(
        det, json.loads((ROOT / "plugins/calibration/schemas/board_detections.schema.json").read_text())
    )
    assert det["board"] == "chessboard:10x7:200mm" and len(det["views"]) == 13
    assert {r["name"] for r in det["rejected"]} == {"im_07.png", "im_03.png"}
    assert [r["unreadable"] for r in sorted(det["rejected"], key=lambda r: r["name"])] == [True, False]
    assert all(len(v["ids"]) == len(v["image_points_px"]) == len(v["object_points_m"]) == 54 for v in det["views"])
    assert all(v["used"] and v["left_out"] is None for v in det["views"])


def test_cli_bad_input_is_exit_2(tmp_path, capsys):
    poses = tmp_path / "poses.txt"
    poses.write_text("\n".join((SYNTH_DIR / "RobotPosesVec.txt").read_text().splitlines()[:14]) + "\n")
    code, _, err = _run(capsys, "--images", SYNTH_DIR, "--poses", poses, "--board", "chessboard:10x7:200mm")
    assert code == 2 and "15 image(s)" in err and "14 robot pose(s)" in err
    code, _, err = _run(capsys, "--images", SYNTH_DIR, "--board", "chessboard:10x7:200mm")
    assert code == 2 and "--poses" in err
    poses.write_text("1 2 3\n")
    code, _, err = _run(capsys, "--images", SYNTH_DIR, "--poses", poses, "--board", "chessboard:10x7:200mm")
    assert code == 2 and "3 numbers" in err
