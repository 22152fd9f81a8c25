"""The set-up (eye in hand / eye to hand) is found from the data when not given, and refused when
the data cannot tell; a given set-up wins. MoveIt's real file is in test_handeye_moveit_data.py."""

import numpy as np
import pytest
from scipy import stats

from engine.transforms import pose_delta
from plugins.calibration.handeye import NoiseModel, calibrate_hand_eye, calibrate_robot_world
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.assemble import AccuracyTargets
from plugins.calibration.handeye.ml_model import EivModel
from plugins.calibration.handeye.noise import PoseNoise
from plugins.calibration.handeye.setup_choice import compare_setups, sample_log_likelihood
from plugins.calibration.handeye.solver import _Run, _solve
from plugins.calibration.handeye.validation import validate_samples

NOISE = NoiseModel.isotropic(0.01, 0.1, 0.1, 0.5)
OTHER = {"eye_in_hand": "eye_to_hand", "eye_to_hand": "eye_in_hand"}


def _scene(setup: str, seed: int, n: int = 10, noise: NoiseModel = NOISE, **view) -> sim.Scene:
    rng = np.random.default_rng(seed)
    return sim.add_noise(sim.viewing_scene(rng, n, setup, **view), noise, rng)


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_the_setup_is_found_from_simulated_data(setup):
    meas = _scene(setup, 2)
    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, noise=NOISE)  # no set-up given
    assert res.usable and res.estimate["setup"] == setup
    m = res.metrics
    assert m["setup_found_from_data"] == 1.0 and m["setup_p_value"] < 1e-3
    assert res.reasons[0].startswith(f"set-up {setup} found from the data") and OTHER[setup] in res.reasons[0]
    # the other set-up's misfit is reported, and it is far worse than the chosen one's
    assert m["other_setup_chain_spread_trans_rms_m"] > 10 * m["chain_spread_trans_rms_m"]
    assert m["other_setup_noise_scale"] > 100
    x = "T_tcp_cam" if setup == "eye_in_hand" else "T_base_cam"
    d = pose_delta(res.estimate[x], meas.X)[0]
    assert np.all(np.abs(d) < 5 * np.sqrt(np.diag(res.covariance)[:6]))


def test_the_setup_is_found_with_the_noise_estimated_and_for_robot_world():
    meas = _scene("eye_to_hand", 3, n=12, noise=NoiseModel.isotropic(0.01, 0.1, 1.0, 2.0))
    res = calibrate_robot_world(meas.T_base_tcp, meas.T_cam_target)
    assert res.usable and res.estimate["setup"] == "eye_to_hand" and res.kind == "robot_world"
    assert res.metrics["noise_estimated"] == 1.0 and res.metrics["setup_vuong_z"] > 3.29
    assert "found from the data" in res.method


def test_a_given_setup_wins_and_is_not_tested():
    meas = _scene("eye_to_hand", 4)
    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, setup="eye_to_hand", noise=NOISE)
    assert res.usable and "setup_found_from_data" not in res.metrics
    assert not any("found from the data" in r for r in res.reasons)


def test_rotations_about_one_axis_refuse_to_guess_the_setup():
    """Rolls about the optical axis only: degenerate for X, and the set-ups cannot be told apart."""
    meas = _scene("eye_in_hand", 30, n=12, max_tilt_deg=0.0, max_roll_deg=60.0)
    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, noise=NOISE)
    assert res.verdict == "degenerate" and not res.usable and "setup" not in res.estimate
    assert "the set-up cannot be found from these data" in res.reasons[-1]
    assert any("--setup" in a for a in res.advice) and any("tilt" in a for a in res.advice)


def test_noisy_small_motions_that_fit_both_setups_refuse_to_guess():
    """5 poses turned by a few degrees under 2 deg of camera noise: both set-ups fit (Vuong's p ~ 0.5)."""
    noise = NoiseModel.isotropic(0.01, 0.1, 2.0, 3.0)
    meas = _scene("eye_in_hand", 2, n=5, noise=noise, max_tilt_deg=8.0, max_roll_deg=8.0)
    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, noise=noise)
    assert res.verdict == "degenerate" and res.metrics["setup_p_value"] > 0.01
    assert "fit them about equally well" in res.reasons[0]
    assert "as eye_in_hand the pose chains spread by" in res.reasons[0] and "as eye_to_hand" in res.reasons[0]
    given = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, setup="eye_in_hand", noise=noise)
    assert given.estimate["setup"] == "eye_in_hand"  # stating the set-up solves it


def test_vuong_test_is_symmetric_and_refuses_a_tie():
    rng = np.random.default_rng(0)
    a, e = rng.normal(size=30), rng.normal(size=30)
    tie = compare_setups({"eye_in_hand": a, "eye_to_hand": a + 1e-3 * e})
    assert tie.chosen is None and tie.p_value > 0.001
    worse = a - 3.0 + 0.5 * e
    better = compare_setups({"eye_in_hand": a, "eye_to_hand": worse})
    swapped = compare_setups({"eye_in_hand": worse, "eye_to_hand": a})
    assert better.chosen == "eye_in_hand" and swapped.chosen == "eye_to_hand"
    d = a - worse
    assert better.z == pytest.approx(d.sum() / (np.sqrt(30) * d.std(ddof=1))) and swapped.z == pytest.approx(better.z)
    assert better.p_value == pytest.approx(2 * stats.t.sf(better.z, 29))
    assert better.log_likelihood_ratio == pytest.approx(d.sum())


@pytest.fixture(scope="module")
def robot_free_fit():
    meas = _scene("eye_to_hand", 5, n=8)
    data = validate_samples(meas.T_base_tcp, meas.T_cam_target)
    run = _Run("hand_eye", "auto", NOISE, False, "huber", "auto", None, AccuracyTargets(), 0)
    return data, _solve(run, "eye_to_hand", data, given=True).fit


def test_sample_likelihood_uses_the_chain_misfit_covariance(robot_free_fit):
    """log det C_i from the nuisance Jacobian equals det(S_c + G S_r G^T) built explicitly."""
    data, fit = robot_free_fit
    model = EivModel("eye_to_hand", data.T_base_tcp, data.T_cam_target, fit.noise, fit.X, fit.Y, fit.M)
    st = model.state(np.zeros(model.n_params), jacobian=True)
    lik = sample_log_likelihood("eye_to_hand", data.T_base_tcp, data.T_cam_target, fit)
    s2 = np.sum(model.whitened(st) ** 2, axis=1)
    for i in range(3):
        A_r = st.J_nuis[i, :6] / model.w_robot[:, None]
        A_c = st.J_nuis[i, 6:] / model.w_camera[:, None]
        G = A_c @ np.linalg.inv(A_r)
        C = fit.noise.camera.covariance() + G @ fit.noise.robot.covariance() @ G.T
        k = lik.scale
        want = -0.5 * (min(s2[i] / k, stats.chi2.ppf(0.999, 6)) + np.linalg.slogdet(k * C)[1] + 6 * np.log(2 * np.pi))
        assert lik.loglik[i] == pytest.approx(want, rel=1e-9, abs=1e-9)


def test_sample_likelihood_does_not_depend_on_the_noise_level_only_its_shape(robot_free_fit):
    data, fit = robot_free_fit
    base = sample_log_likelihood("eye_to_hand", data.T_base_tcp, data.T_cam_target, fit)
    n = fit.noise
    scaled = NoiseModel(
        PoseNoise(np.asarray(n.robot.rot_sigma) * 3, np.asarray(n.robot.trans_sigma) * 3),
        PoseNoise(np.asarray(n.camera.rot_sigma) * 3, np.asarray(n.camera.trans_sigma) * 3),
    )
    fit3 = type(fit)(**{**fit.__dict__, "noise": scaled})
    other = sample_log_likelihood("eye_to_hand", data.T_base_tcp, data.T_cam_target, fit3)
    assert np.allclose(other.loglik, base.loglik, atol=1e-9) and other.scale == pytest.approx(base.scale / 9)
