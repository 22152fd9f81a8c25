"""An AR-tag data set in camodocal's OpenCV YAML layout (tests/handeye/data/ar_tag_pairs.yml, made by
its seeded script): read, set-up found, a degree of tag noise accepted at the default noise limits,
the limits as options, outliers named by the file's sample ids."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from plugins.calibration.handeye import AccuracyTargets, calibrate_hand_eye, load_pose_pairs
from plugins.calibration.handeye.report import format_report

DATA = Path(__file__).parent / "data"
FILE = DATA / "ar_tag_pairs.yml"


def _generator():
    spec = importlib.util.spec_from_file_location("make_ar_tag_pairs", DATA / "make_ar_tag_pairs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def samples():
    return load_pose_pairs(FILE)


@pytest.fixture(scope="module")
def found(samples):
    return calibrate_hand_eye(samples.T_base_tcp, samples.T_cam_target, sample_ids=samples.ids)


def test_the_committed_file_is_what_its_script_makes(samples, tmp_path):
    made = load_pose_pairs(_generator().main(tmp_path / "again.yml"))
    assert np.allclose(made.T_base_tcp, samples.T_base_tcp, atol=1e-12)
    assert np.allclose(made.T_cam_target, samples.T_cam_target, atol=1e-12)
    assert samples.ids == [str(i) for i in range(20)]


def test_defaults_find_eye_to_hand_and_accept_a_degree_of_tag_noise(found):
    truth = _generator().make()
    assert found.usable and found.estimate["setup"] == "eye_to_hand"
    m = found.metrics
    assert np.rad2deg(m["noise_camera_rot_rad"]) > 1.0  # the old hard-coded limit would have failed it
    assert m["noise_limit_camera_rot_rad"] == pytest.approx(np.deg2rad(5.0))
    d = found.estimate["T_base_cam"][:3, 3] - truth.X[:3, 3]
    assert np.all(np.abs(d) < 4 * np.sqrt(np.diag(found.covariance)[:3]))
    assert "noise limits (an estimated noise above one fails): robot 1 deg / 10 mm, camera 5 deg / 20 mm" in (
        format_report(found)
    )


IDS = [f"T1_{i}/T2_{i}" for i in range(20)]  # any id the caller has


@pytest.fixture(scope="module")
def given(samples):
    return calibrate_hand_eye(samples.T_base_tcp, samples.T_cam_target, setup="eye_to_hand", sample_ids=IDS)


def test_outliers_are_named_by_the_files_sample_ids(given):
    res, ids = given, IDS
    flagged = [ids[k] for k in np.flatnonzero(res.outliers)]
    assert "T1_13/T2_13" in flagged  # the flipped tag
    reason = next(r for r in res.reasons if "outlier sample(s)" in r)
    assert "T1_13/T2_13" in reason
    assert res.estimate["sample_labels"] == ids
    row = next(ln for ln in format_report(res).splitlines() if ln.strip().startswith("T1_13/T2_13"))
    assert row.endswith("OUTLIER")


@pytest.mark.parametrize(
    ("limits", "who"),
    [
        ({"max_camera_noise_rot_rad": np.deg2rad(0.5)}, "camera"),
        ({"max_camera_noise_trans_m": 1e-3}, "camera"),
        ({"max_robot_noise_rot_rad": np.deg2rad(1e-3)}, "robot"),
    ],
)
def test_a_lower_noise_limit_fails_the_same_data_and_says_which(samples, given, limits, who):
    res = calibrate_hand_eye(
        samples.T_base_tcp, samples.T_cam_target, setup="eye_to_hand", accuracy=AccuracyTargets(**limits)
    )
    assert res.verdict == "failed"
    reason = next(r for r in res.reasons if "pose noise of" in r)
    assert f"{who} " in reason and "limit" in reason
    assert any("--max-camera-noise" in a for a in res.advice)
    assert given.usable  # the same data at the default limits
