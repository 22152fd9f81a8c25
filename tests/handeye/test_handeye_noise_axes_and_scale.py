"""Hand-eye on the noise real cameras have and the units they give: the camera's noise estimated per
axis (a depth camera's or PnP's error is largest along the optical axis), outlier flags that chance
explains earning no warning, and a camera whose translations are in an unknown unit (``scale="free"``)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from plugins.calibration.handeye import calibrate_hand_eye, calibrate_robot_world
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.assemble import AccuracyTargets, _chance_of_flags, _check_outliers
from plugins.calibration.handeye.free_scale import scaled
from plugins.calibration.handeye.noise import NoiseModel, PoseNoise
from plugins.calibration.handeye.validation import HandEyeInputError
from plugins.calibration.result import CalibrationResult

# a depth camera seen through PnP: 4 mm along the optical axis (z), 1.2 mm across
DEPTH = NoiseModel(PoseNoise.from_deg_mm(0.01, 0.1), PoseNoise.from_deg_mm([0.3, 0.3, 0.1], [1.2, 1.2, 4.0]))
ISO = NoiseModel(PoseNoise.from_deg_mm(0.01, 0.1), PoseNoise.from_deg_mm(0.1, 0.5))


def _scene(seed: int, n: int, noise: NoiseModel) -> sim.Scene:
    rng = np.random.default_rng(seed)
    return sim.add_noise(sim.viewing_scene(rng, n), noise, rng)


def test_depth_dominated_camera_noise_is_estimated_per_axis_and_flags_no_good_sample():
    flagged, total, z_over_x = 0, 0, []
    for seed in range(4):
        s = _scene(300 + seed, 60, DEPTH)
        res = calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, setup="eye_in_hand")
        assert res.usable, res.reasons
        flagged += int(np.count_nonzero(res.outliers))
        total += len(res.outliers)
        m = res.metrics
        z_over_x.append(m["noise_camera_sigma_tz_m"] / m["noise_camera_sigma_tx_m"])
        assert 2.5e-3 < m["noise_camera_sigma_tz_m"] < 5.5e-3  # truth 4 mm
    assert flagged <= 0.01 * total  # (with one noise per translation and rotation: 6.7 % flagged)
    assert 2.0 < np.median(z_over_x) < 5.0  # truth 3.3


def test_depth_noise_per_axis_is_what_an_axis_wise_declaration_says_too():
    s = _scene(311, 40, DEPTH)
    declared = calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, setup="eye_in_hand", noise=DEPTH)
    assert declared.usable and declared.metrics["noise_camera_sigma_tz_m"] == pytest.approx(4e-3)
    assert not np.any(declared.outliers)


def _flags(n: int, flagged: dict[int, float]) -> SimpleNamespace:
    s2 = np.full(n, 5.0)
    out = np.zeros(n, dtype=bool)
    for k, v in flagged.items():
        s2[k], out[k] = v, True
    return SimpleNamespace(outliers=out, s2=s2, outlier_quantile=0.999)


def test_flags_that_chance_explains_are_named_without_a_warning_and_gross_ones_warn():
    acc = AccuracyTargets()
    # one sample just past the 99.9 % threshold among 600: expected by chance (0.6 such per set)
    mild = _flags(600, {7: 24.0})
    assert _chance_of_flags(mild, 1.0) > 0.1  # (0.27: one such sample or farther out among 600)
    reasons: list[str] = []
    assert _check_outliers(mild, [str(k) for k in range(600)], "huber", 1.0, acc, "ok", reasons, []) == "ok"
    assert "by chance" in reasons[0] and "7" in reasons[0]
    # the same count, far out: not chance
    gross = _flags(600, {7: 400.0})
    assert _chance_of_flags(gross, 1.0) < 1e-6
    assert _check_outliers(gross, [str(k) for k in range(600)], "huber", 1.0, acc, "ok", [], []) == "warning"
    # many mild flags: more than chance gives
    many = _flags(600, dict.fromkeys(range(8), 24.0))
    assert _check_outliers(many, [str(k) for k in range(600)], "huber", 1.0, acc, "ok", [], []) == "warning"


@pytest.mark.parametrize("k", [1e-3, 0.37, 25.0])
def test_an_unknown_camera_scale_is_solved_with_an_honest_sigma(k):
    """Camera translations in units of 1/k metres (1e-3: millimetres); the scale comes back as
    metres per camera unit, within its reported sigma, and X as accurate as with the scale known."""
    s = _scene(420, 30, ISO)
    B = scaled(s.T_cam_target, 1.0 / k)
    res = calibrate_hand_eye(s.T_base_tcp, B, setup="eye_in_hand", scale="free")
    known = calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, setup="eye_in_hand")
    assert res.usable, res.reasons
    got, sd = res.metrics["camera_scale"], res.metrics["camera_scale_sd"]
    assert res.estimate["camera_scale"] == got and 0 < sd < 0.01 * got
    assert abs(got - k) < 4.0 * sd
    err = np.linalg.norm(res.estimate["T_tcp_cam"][:3, 3] - s.X[:3, 3])
    err_known = np.linalg.norm(known.estimate["T_tcp_cam"][:3, 3] - s.X[:3, 3])
    assert err < 1.5e-3 and err < 2.0 * err_known + 2e-4
    assert "camera scale solved" in res.reasons[0]
    # the uncertainty of X includes the scale's
    assert np.all(np.diag(res.covariance)[:3] >= np.diag(known.covariance)[:3] * 0.5)
    back = CalibrationResult.from_dict(json.loads(res.to_json()))
    assert back.estimate["camera_scale"] == pytest.approx(got)


def test_a_scale_the_motions_cannot_show_is_failed_and_says_what_to_add():
    s = _scene(421, 12, ISO)
    M = s.T_base_tcp.copy()
    M[:, :3, :3] = M[0, :3, :3]  # pure translations: no screw shows the scale
    B = np.linalg.inv(s.X) @ np.linalg.inv(M) @ s.Y  # eye in hand: B = X^-1 A^-1 Y
    res = calibrate_hand_eye(M, B, setup="eye_in_hand", scale="free")
    assert res.verdict == "failed" and "cannot be solved" in res.reasons[0]
    assert any("rotate" in a for a in res.advice)


def test_robot_world_solves_the_scale_too_and_a_wrong_scale_option_is_refused():
    s = _scene(422, 25, ISO)
    res = calibrate_robot_world(s.T_base_tcp, scaled(s.T_cam_target, 2.0), setup="eye_in_hand", scale="free")
    assert res.usable and res.kind == "robot_world"
    assert abs(res.metrics["camera_scale"] - 0.5) < 4 * res.metrics["camera_scale_sd"]
    with pytest.raises(ValueError, match="scale must be"):
        calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, scale="auto")  # type: ignore[arg-type]


def test_a_factor_no_unit_gives_points_to_the_free_scale():
    s = _scene(423, 15, ISO)
    with pytest.raises(HandEyeInputError, match="scale='free'"):
        calibrate_hand_eye(s.T_base_tcp, scaled(s.T_cam_target, 7.0), setup="eye_in_hand")
    with pytest.raises(HandEyeInputError, match="robot poses look like centimetres"):
        calibrate_hand_eye(s.T_base_tcp, scaled(s.T_cam_target, 0.01), setup="eye_in_hand")
