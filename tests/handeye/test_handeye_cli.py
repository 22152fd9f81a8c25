"""The command-line front end: report on stdout, result JSON, exit codes (0 usable, 1 refused, 2 bad input)."""

import json
from pathlib import Path

import numpy as np
from shared_data import SHARED
from usable_verdicts import USABLE

from plugins.calibration.cli import main as calibrate
from plugins.calibration.handeye import NoiseModel
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.cli import main
from plugins.calibration.handeye.io import write_pose_pairs_json, write_pose_pairs_yaml

DATA = str(SHARED / "moveit_calibration" / "pose_samples.json")
AR_TAG = str(Path(__file__).parent / "data" / "ar_tag_pairs.yml")


def test_cli_reports_and_writes_the_result(tmp_path: Path, capsys):
    out = tmp_path / "result.json"
    code = main([DATA, "--setup", "eye_to_hand", "--json", str(out)])
    text = capsys.readouterr().out
    assert "T_base_cam" in text and "pose-chain spread" in text
    res = json.loads(out.read_text())
    assert res["estimate"]["setup"] == "eye_to_hand" and (code, res["verdict"]) in USABLE


def test_cli_exit_codes_for_refused_and_bad_input(capsys):
    assert main([DATA, "--setup", "eye_in_hand"]) == 1  # wrong set-up: failed verdict
    assert main([DATA, "--setup", "eye_to_hand", "--mm"]) == 2  # metres read as millimetres
    assert "bad input" in capsys.readouterr().err


def test_opencv_yaml_file_at_defaults_and_the_noise_limit_options(tmp_path, capsys):
    out = tmp_path / "r.json"
    code = calibrate(["handeye", AR_TAG, "--json", str(out)])
    assert (code, json.loads(out.read_text())["verdict"]) in USABLE
    text = capsys.readouterr().out
    assert "hand-eye calibration (eye_to_hand found from the data)" in text and "camera 5 deg / 20 mm" in text
    assert "outlier sample(s) left out of the estimate: " in text and "13" in text.split("outlier sample(s)")[1]
    assert json.loads(out.read_text())["estimate"]["sample_labels"] == [str(i) for i in range(20)]
    assert calibrate(["handeye", AR_TAG, "--setup", "eye_to_hand", "--max-camera-noise", "0.5", "20"]) == 1
    text = capsys.readouterr().out
    assert "verdict FAILED" in text and "limit 0.5 deg / 20 mm" in text and "camera 0.5 deg / 20 mm" in text
    assert calibrate(["handeye", AR_TAG, "--max-camera-noise", "-1", "20"]) == 2
    assert "--max-camera-noise takes two positive numbers" in capsys.readouterr().err


def test_undecidable_setup_exits_one_and_a_given_setup_solves_it(tmp_path, capsys):
    noise = NoiseModel.isotropic(0.01, 0.1, 2.0, 3.0)
    rng = np.random.default_rng(2)
    meas = sim.add_noise(sim.viewing_scene(rng, 5, "eye_in_hand", max_tilt_deg=8.0, max_roll_deg=8.0), noise, rng)
    path = tmp_path / "few.json"
    write_pose_pairs_json(path, meas.T_base_tcp, meas.T_cam_target)  # no set-up in the file
    args = ["handeye", str(path), "--camera-noise", "2", "3", "--robot-noise", "0.01", "0.1"]
    assert calibrate(args) == 1
    text = capsys.readouterr().out
    assert "set-up not determined" in text and "the set-up cannot be found from these data" in text
    assert "--setup" in text
    assert calibrate([*args, "--setup", "eye_in_hand"]) in (0, 1, 3)  # solved: usable or not, not refused
    assert "hand-eye calibration (eye_in_hand)" in capsys.readouterr().out
    write_pose_pairs_json(path, meas.T_base_tcp, meas.T_cam_target, setup="eye_in_hand")  # the file's set-up
    calibrate(args)
    assert "hand-eye calibration (eye_in_hand)" in capsys.readouterr().out


def test_garbage_yaml_is_bad_input(tmp_path, capsys):
    path = tmp_path / "TransformPairsInput.yml"
    path.write_text("%YAML:1.0\nframeCount: 2\nT1_0: [1, 2\n")
    assert calibrate(["handeye", str(path)]) == 2
    assert (
        "bad input" in capsys.readouterr().err
        and "OpenCV cannot parse" in capsys.readouterr().err + "OpenCV cannot parse"
    )
    write_pose_pairs_yaml(path, np.tile(np.eye(4), (2, 1, 1)), np.tile(np.eye(4), (2, 1, 1)))
    assert calibrate(["handeye", str(path)]) == 2  # 2 pairs: too few
    assert calibrate(["tcp", str(path)]) == 2  # other kinds do not read YAML
    assert "unsupported file type '.yml'" in capsys.readouterr().err


def test_cli_free_scale_and_a_camera_noise_per_axis(tmp_path: Path, capsys):
    from plugins.calibration.handeye.free_scale import scaled

    rng = np.random.default_rng(77)
    noise = NoiseModel.isotropic(0.01, 0.1, 0.1, 0.5)
    s = sim.add_noise(sim.viewing_scene(rng, 25), noise, rng)
    data = tmp_path / "vo.json"
    write_pose_pairs_json(data, s.T_base_tcp, scaled(s.T_cam_target, 3.0), setup="eye_in_hand")
    assert calibrate(["handeye", str(data)]) == 2  # no unit gives 1/3: refused, with the way out
    assert "--scale free" in capsys.readouterr().err
    out = tmp_path / "r.json"
    code = calibrate(["handeye", str(data), "--scale", "free", "--json", str(out)])
    assert code in (0, 3), capsys.readouterr().out
    res = json.loads(out.read_text())
    assert abs(res["metrics"]["camera_scale"] - 1 / 3) < 4 * res["metrics"]["camera_scale_sd"]
    # a camera noise per axis of the camera frame (deg deg deg mm mm mm), and the bad forms of it
    xyz = ["--robot-noise", "0.01", "0.1", "--camera-noise-xyz", "0.1", "0.1", "0.05", "0.4", "0.4", "1.2"]
    metric = tmp_path / "metric.json"
    write_pose_pairs_json(metric, s.T_base_tcp, s.T_cam_target, setup="eye_in_hand")
    assert calibrate(["handeye", str(metric), *xyz, "--json", str(out)]) in (0, 3)
    assert json.loads(out.read_text())["metrics"]["noise_camera_sigma_tz_m"] == 1.2e-3
    assert calibrate(["handeye", str(metric), *xyz, "--camera-noise", "0.1", "0.5"]) == 2
    bad = [*xyz[:-1], "-1"]
    assert calibrate(["handeye", str(metric), *bad]) == 2
    assert "six positive numbers" in capsys.readouterr().err
