"""Real data: MoveIt calibration's 50 pose pairs, eye-to-hand, against MoveIt's asserted camera pose.

MoveIt's test (handeye_solver_test.cpp) asserts T_base_cam translation (0.659, -0.249, 0.830) m and
Eigen ``eulerAngles(0, 1, 2)`` = (0.230, -2.540, 1.950) rad, each with Eigen's ``isApprox(.., 0.01)``
(``|a - b| <= 0.01 * min(|a|, |b|)``).
"""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from shared_data import SHARED
from usable_verdicts import USABLE

from plugins.calibration.cli import main as calibrate
from plugins.calibration.handeye import CLOSED_FORM_METHODS, calibrate_hand_eye, closed_form
from plugins.calibration.handeye.io import load_pose_pairs
from plugins.calibration.handeye.report import format_report
from plugins.calibration.result import CalibrationResult

DATA = SHARED / "moveit_calibration" / "pose_samples.json"
T_REF = np.array([0.659, -0.249, 0.830])
EULER_REF = np.array([0.230, -2.540, 1.950])


def eigen_euler_xyz(R: np.ndarray) -> np.ndarray:
    """Eigen's ``R.eulerAngles(0, 1, 2)``: R = Rx(a) Ry(b) Rz(c) with a in [0, pi]."""
    a, b, c = Rotation.from_matrix(R).as_euler("XYZ")
    if a < 0.0:
        a, b, c = a + np.pi, np.pi - b, c + np.pi
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    return np.array([a, wrap(b), wrap(c)])


def is_approx(a: np.ndarray, b: np.ndarray, prec: float = 0.01) -> bool:
    return bool(np.linalg.norm(a - b) <= prec * min(np.linalg.norm(a), np.linalg.norm(b)))


@pytest.fixture(scope="module")
def samples():
    return load_pose_pairs(DATA)


@pytest.fixture(scope="module")
def result(samples):
    return calibrate_hand_eye(samples.T_base_tcp, samples.T_cam_target, setup="eye_to_hand")


def test_eye_to_hand_matches_moveit_within_one_percent(result):
    assert result.usable
    T = result.estimate["T_base_cam"]
    assert is_approx(T[:3, 3], T_REF)
    assert is_approx(eigen_euler_xyz(T[:3, :3]), EULER_REF)
    # far inside: MoveIt's reference is rounded to 1 mm
    assert np.max(np.abs(T[:3, 3] - T_REF)) < 1.5e-3


def test_eye_to_hand_residuals_and_pose_chain_spread_are_reported(result):
    text = format_report(result)
    print("\n" + text)  # shown with pytest -s: the real-data report
    m = result.metrics
    assert "pose-chain spread" in text and "per-sample residuals" in text
    assert result.residuals.shape == (50, len(result.residual_names))
    # MoveIt's detections: about 4.6 mm / 0.09 deg RMS chain spread, no outliers, noise of a
    # few mm in the camera (estimated from the data), so the calibration is good to about 1 mm
    assert 1e-3 < m["chain_spread_trans_rms_m"] < 1e-2
    assert m["chain_spread_rot_rms_rad"] < np.deg2rad(0.3)
    assert m["n_outliers"] == 0
    assert m["std_x_trans_m"] < 2e-3
    assert m["unit_scale_robot_per_camera"] == pytest.approx(1.0, abs=0.005)


@pytest.mark.parametrize("method", CLOSED_FORM_METHODS)
def test_every_closed_form_reproduces_moveit(samples, method):
    X, _ = closed_form("eye_to_hand", samples.T_base_tcp, samples.T_cam_target, method)
    assert is_approx(X[:3, 3], T_REF) and is_approx(eigen_euler_xyz(X[:3, :3]), EULER_REF)


def test_the_same_data_as_eye_in_hand_is_refused(samples):
    res = calibrate_hand_eye(samples.T_base_tcp, samples.T_cam_target, setup="eye_in_hand")
    assert res.verdict == "failed" and "eye_to_hand" in res.reasons[-1]


def test_at_the_command_lines_defaults_the_setup_is_found_and_matches_moveit(tmp_path, result):
    """``vgr calibrate handeye pose_samples.json`` with no option: eye to hand, MoveIt's camera pose."""
    out = tmp_path / "result.json"
    code = calibrate(["handeye", str(DATA), "--json", str(out), "--no-samples"])
    found = CalibrationResult.from_dict(json.loads(out.read_text()))
    assert (code, found.verdict) in USABLE and found.estimate["setup"] == "eye_to_hand"
    T = found.estimate["T_base_cam"]
    assert np.max(np.abs(T[:3, 3] - T_REF)) < 1.5e-3
    assert is_approx(T[:3, 3], T_REF) and is_approx(eigen_euler_xyz(T[:3, :3]), EULER_REF)
    assert np.allclose(T, result.estimate["T_base_cam"], atol=1e-9)  # the same answer as with the set-up given
    m = found.metrics
    assert m["setup_found_from_data"] == 1.0 and m["setup_vuong_z"] > 10 and m["setup_p_value"] < 1e-12
    # as eye in hand, each sample's own T_base_target lands a quarter of a metre from the others
    assert m["other_setup_chain_spread_trans_rms_m"] > 0.1 and m["chain_spread_trans_rms_m"] < 0.01
    assert found.reasons[0].startswith("set-up eye_to_hand found from the data")
