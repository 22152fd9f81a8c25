"""Bad input gives a clear error or a warning, never a silent wrong answer (hypothesis-driven)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from engine.transforms import pose_delta
from plugins.calibration.handeye import HandEyeInputError, NoiseModel, calibrate_hand_eye
from plugins.calibration.handeye import simulate as sim

NOISE = NoiseModel.isotropic(0.02, 0.1, 0.1, 0.5)
SCENE = sim.add_noise(sim.viewing_scene(np.random.default_rng(40), 12, "eye_in_hand"), NOISE, np.random.default_rng(41))
CLEAN = calibrate_hand_eye(SCENE.T_base_tcp, SCENE.T_cam_target, setup="eye_in_hand", noise=NOISE)
FAST = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

sample = st.integers(0, 11)
which = st.sampled_from(["robot", "camera"])


def _copies():
    return SCENE.T_base_tcp.copy(), SCENE.T_cam_target.copy()


@FAST
@given(sample, which, st.integers(0, 2), st.integers(0, 3), st.sampled_from([np.nan, np.inf, -np.inf]))
def test_nan_or_inf_is_an_error_naming_the_sample(i, side, r, c, bad):
    M, B = _copies()
    (M if side == "robot" else B)[i, r, c] = bad
    with pytest.raises(HandEyeInputError, match=rf"NaN or infinity in sample\(s\) {i}\b"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)


@FAST
@given(sample, which, st.floats(2e-3, 0.5))
def test_non_orthonormal_rotation_is_an_error(i, side, eps):
    M, B = _copies()
    (M if side == "robot" else B)[i, 0, 0] += eps
    with pytest.raises(HandEyeInputError, match=r"not orthonormal|det <= 0"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)


@FAST
@given(sample, which, st.floats(2e-6, 4e-4))  # |R^T R - I| = 2 eps
def test_slightly_non_orthonormal_rotation_is_repaired_with_a_warning(i, side, eps):
    M, B = _copies()
    (M if side == "robot" else B)[i, :3, :3] *= 1.0 + eps
    res = calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)
    assert any("re-orthonormalised" in r for r in res.reasons) and res.verdict != "ok"
    d = pose_delta(res.estimate["T_tcp_cam"], CLEAN.estimate["T_tcp_cam"])[0]
    assert np.all(np.abs(d) < 0.2 * np.sqrt(np.diag(CLEAN.covariance)[:6]))


@FAST
@given(sample, which)
def test_reflection_is_an_error(i, side):
    M, B = _copies()
    (M if side == "robot" else B)[i, :3, 2] *= -1.0
    with pytest.raises(HandEyeInputError, match="det <= 0"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)


def test_bad_last_row_and_shapes_are_errors():
    M, B = _copies()
    M[3, 3, 0] = 0.1
    with pytest.raises(HandEyeInputError, match="last row"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)
    with pytest.raises(HandEyeInputError, match="12 robot poses but 11 camera poses"):
        calibrate_hand_eye(SCENE.T_base_tcp, SCENE.T_cam_target[:11], setup="eye_in_hand", noise=NOISE)
    with pytest.raises(HandEyeInputError, match="4x4"):
        calibrate_hand_eye(SCENE.T_base_tcp[:, :3, :], SCENE.T_cam_target[:, :3, :], setup="eye_in_hand", noise=NOISE)
    with pytest.raises(HandEyeInputError, match="no samples"):
        calibrate_hand_eye(np.zeros((0, 4, 4)), np.zeros((0, 4, 4)), setup="eye_in_hand", noise=NOISE)


@FAST
@given(which, st.sampled_from([1000.0, 100.0, 10.0, 0.1, 0.001]))
def test_mixed_or_wrong_length_units_are_errors(side, factor):
    M, B = _copies()
    (M if side == "robot" else B)[:, :3, 3] *= factor
    with pytest.raises(HandEyeInputError, match=r"millimetres|units"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)


def test_both_sides_in_millimetres_is_an_error():
    M, B = _copies()
    M[:, :3, 3] *= 1000.0
    B[:, :3, 3] *= 1000.0
    with pytest.raises(HandEyeInputError, match="look like millimetres"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)


def test_slightly_wrong_camera_scale_is_a_warning():
    M, B = _copies()
    B[:, :3, 3] *= 1.03  # e.g. a wrong calibration-target square size
    res = calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)
    assert res.verdict != "ok" and any("calibration-target size" in r for r in res.reasons)


@FAST
@given(st.lists(sample, min_size=1, max_size=5))
def test_exact_duplicates_are_dropped_with_a_warning(dups):
    M, B = _copies()
    M2 = np.concatenate([M, M[dups]])
    B2 = np.concatenate([B, B[dups]])
    res = calibrate_hand_eye(M2, B2, setup="eye_in_hand", noise=NOISE)
    assert any("duplicate" in r for r in res.reasons) and res.verdict != "ok"
    assert res.metrics["n_samples"] == 12
    assert np.allclose(res.estimate["T_tcp_cam"], CLEAN.estimate["T_tcp_cam"], atol=1e-9)


def test_samples_are_named_by_the_callers_ids_in_errors_warnings_and_the_result():
    ids = [f"pose-{k:02d}" for k in range(12)]
    M, B = _copies()
    M[7, 0, 3] = np.nan
    with pytest.raises(HandEyeInputError, match=r"NaN or infinity in sample\(s\) pose-07$"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE, sample_ids=ids)
    with pytest.raises(HandEyeInputError, match="11 sample ids for 12 samples"):
        calibrate_hand_eye(*_copies(), setup="eye_in_hand", noise=NOISE, sample_ids=ids[:11])
    M, B = _copies()
    B[7] = B[6]  # a stale detection
    M2, B2 = np.concatenate([M, M[3:4]]), np.concatenate([B, B[3:4]])
    res = calibrate_hand_eye(M2, B2, setup="eye_in_hand", noise=NOISE, sample_ids=[*ids, "copy-of-03"])
    assert any("duplicate" in r and "copy-of-03" in r for r in res.reasons)
    assert any("pose-07 repeats pose-06" in r for r in res.reasons)
    assert res.estimate["sample_labels"] == ids  # one per residual row: the copy was dropped
    out = [ids[k] for k in np.flatnonzero(res.outliers)]
    assert out and any(", ".join(out) in r for r in res.reasons if "outlier sample(s)" in r)


def test_stale_camera_observation_is_reported_and_flagged():
    M, B = _copies()
    B[7] = B[6]  # the detector returned the previous frame
    res = calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)
    assert any("stale" in r for r in res.reasons)
    assert res.outliers[7] or res.outliers[6]


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 10_000),
    st.integers(3, 14),
    st.floats(0.0, 35.0),
    st.floats(0.0, 60.0),
    st.floats(0.2, 3.0),
    st.sampled_from(["eye_in_hand", "eye_to_hand"]),
)
def test_never_a_silent_wrong_answer(seed, n, tilt, roll, noise_scale, setup):
    """Whatever the motion set: either refused, or the truth is inside the reported uncertainty."""
    rng = np.random.default_rng(seed)
    truth = sim.viewing_scene(rng, n, setup, max_tilt_deg=tilt, max_roll_deg=roll)
    noise = NoiseModel.isotropic(0.02 * noise_scale, 0.1 * noise_scale, 0.1 * noise_scale, 0.5 * noise_scale)
    meas = sim.add_noise(truth, noise, rng)
    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, setup=setup, noise=noise)
    assert res.verdict in ("ok", "warning", "degenerate", "failed")
    if not res.usable:
        assert res.reasons and (res.verdict != "degenerate" or res.advice)
        return
    x_name = res.param_names[0].split(".")[0]
    d = pose_delta(res.estimate[x_name], truth.X)[0]
    assert np.all(np.isfinite(res.covariance))
    # far beyond any 1e-4 chance event: a usable answer is consistent with its own covariance
    assert d @ np.linalg.solve(res.covariance[:6, :6], d) < stats.chi2.ppf(1 - 1e-5, 6)


def test_metres_read_as_millimetres_is_an_error():
    M, B = _copies()
    M[:, :3, 3] /= 1000.0
    B[:, :3, 3] /= 1000.0
    with pytest.raises(HandEyeInputError, match="metres read as millimetres"):
        calibrate_hand_eye(M, B, setup="eye_in_hand", noise=NOISE)
