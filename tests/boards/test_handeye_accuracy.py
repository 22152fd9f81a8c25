"""The pixel refinement's statistics on simulated hand-eye data with known truth
(:mod:`plugins.calibration.boards.handeye_sim`): the robot-pose and corner noise estimated from the
corners, the reported covariance against the actual error (Mahalanobis²), the Cramér–Rao bound,
and the outlier test's bad input. The tight figures (hundreds of seeds) are in
``benchmarks/handeye_images_crlb.py``; these tests use few seeds and bounds that a wrong
covariance or an inefficient estimator still break."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.transforms import pose_delta
from plugins.calibration.boards.handeye_images import calibrate_handeye_images, moved_views
from plugins.calibration.boards.handeye_sim import SIM_CAMERA, simulate_handeye
from plugins.calibration.boards.reprojection import RobotNoise, crlb, refine_reprojection
from plugins.camera.board_spec import parse_board

BOARD = parse_board("chessboard:10x7:30mm")
ROBOT = RobotNoise(2e-4, float(np.radians(0.02)))


def _mahalanobis2(X, X_true, cov):
    e = pose_delta(X, X_true)[0]
    return float(e @ np.linalg.solve(cov[:6, :6], e)), e


@pytest.fixture(scope="module")
def noisy_robot_trials():
    """12 seeds, corners with N(0, 0.1 px), robot poses with 0.2 mm / 0.02 deg: per trial the default
    result, the robot-noise result and the exact-robot refinement's own covariance."""
    out = []
    for seed in range(12):
        sim = simulate_handeye(BOARD, SIM_CAMERA, 15, np.random.default_rng(100 + seed), robot_noise=ROBOT)
        default = calibrate_handeye_images(sim.views, sim.T_base_tcp, SIM_CAMERA, holdout=False)
        noisy = calibrate_handeye_images(sim.views, sim.T_base_tcp, SIM_CAMERA, holdout=False, model_robot_noise=True)
        out.append((sim, default, noisy))
    return out


def test_the_robot_and_corner_noise_are_estimated(noisy_robot_trials):
    m = np.array([[d.result.metrics[k] for k in ("robot_sigma_trans_m", "robot_sigma_rot_rad", "corner_sigma_px")]
                  for _, d, _ in noisy_robot_trials])  # fmt: skip
    med = np.median(m, axis=0)
    assert med[0] == pytest.approx(ROBOT.trans_m, rel=0.25)
    assert med[1] == pytest.approx(ROBOT.rot_rad, rel=0.25)
    assert med[2] == pytest.approx(0.1, rel=0.1)


def test_the_reported_covariance_is_honest_with_robot_noise(noisy_robot_trials):
    # chi-square(6) over 12 trials: mean 6, standard error 1; the exact-robot covariance alone
    # (corner noise only, what the refinement reported before) is far off
    default, noisy, naive = [], [], []
    for sim, d, n in noisy_robot_trials:
        default.append(_mahalanobis2(d.result.estimate["T_tcp_cam"], sim.X, d.result.covariance)[0])
        noisy.append(_mahalanobis2(n.result.estimate["T_tcp_cam"], sim.X, n.result.covariance)[0])
        naive.append(_mahalanobis2(d.refinement.X, sim.X, d.refinement.covariance)[0])
    assert 3.0 < np.mean(default) < 10.0, default
    assert 3.0 < np.mean(noisy) < 10.0, noisy
    assert np.mean(naive) > 50.0, naive


def test_modelling_the_robot_noise_lowers_the_error_when_it_is_random(noisy_robot_trials):
    err_default = [pose_delta(d.result.estimate["T_tcp_cam"], s.X)[0] for s, d, _ in noisy_robot_trials]
    err_noisy = [pose_delta(n.result.estimate["T_tcp_cam"], s.X)[0] for s, _, n in noisy_robot_trials]
    rms = lambda e, sl: np.sqrt(np.mean(np.sum(np.square(e)[:, sl], axis=1)))  # noqa: E731
    assert rms(err_noisy, slice(0, 3)) < 0.6 * rms(err_default, slice(0, 3))  # 0.23 mm against 0.72 mm
    assert rms(err_noisy, slice(3, 6)) < 0.4 * rms(err_default, slice(3, 6))  # 0.021 deg against 0.13 deg
    # and it is near its own Cramér–Rao bound (the robot poses as nuisance parameters)
    bound = [np.trace(crlb("eye_in_hand", s.T_base_tcp_true, s.views, SIM_CAMERA, s.X, s.Y, 0.1,
                           robot_noise=ROBOT)[:3, :3]) for s, _, _ in noisy_robot_trials]  # fmt: skip
    assert rms(err_noisy, slice(0, 3)) < 1.4 * np.sqrt(np.mean(bound))


def test_the_estimate_reaches_the_cramer_rao_bound_with_exact_robot_poses():
    err, bounds, m2 = [], [], []
    for seed in range(40):
        sim = simulate_handeye(BOARD, SIM_CAMERA, 15, np.random.default_rng(500 + seed), sigma_px=0.1)
        X = calibrate_handeye_images(sim.views, sim.T_base_tcp, SIM_CAMERA, holdout=False).result.estimate["T_tcp_cam"]
        C = crlb("eye_in_hand", sim.T_base_tcp, sim.views, SIM_CAMERA, sim.X, sim.Y, 0.1)[:6, :6]
        e = pose_delta(X, sim.X)[0]
        err.append(e**2)
        bounds.append(np.diag(C))
        m2.append(e @ np.linalg.solve(C, e))
    err, bounds = np.array(err), np.array(bounds)
    for sl in (slice(0, 3), slice(3, 6)):  # RMS over 40 trials: about +-10 % of the bound (1 sigma)
        ratio = np.sqrt(err[:, sl].sum(axis=1).mean() / bounds[:, sl].sum(axis=1).mean())
        assert 0.75 < ratio < 1.3, ratio
    assert np.mean(m2) < 8.5  # chi-square(6) over 40 trials: 6 +- 0.55


def test_the_bound_is_the_refinements_covariance_at_the_truth():
    sim = simulate_handeye(BOARD, SIM_CAMERA, 10, np.random.default_rng(7), sigma_px=0.1)
    ref = refine_reprojection("eye_in_hand", sim.T_base_tcp, sim.views, SIM_CAMERA, sim.X, sim.Y)
    C = crlb("eye_in_hand", sim.T_base_tcp, sim.views, SIM_CAMERA, sim.X, sim.Y, ref.sigma_px)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(ref.covariance)), rtol=0.05)
    # the robot's noise can only raise the bound
    Cr = crlb("eye_in_hand", sim.T_base_tcp, sim.views, SIM_CAMERA, sim.X, sim.Y, 0.1, robot_noise=ROBOT)
    assert np.all(np.diag(Cr) > np.diag(crlb("eye_in_hand", sim.T_base_tcp, sim.views, SIM_CAMERA, sim.X, sim.Y, 0.1)))


def test_a_board_that_moved_is_flagged_in_simulation():
    sim = simulate_handeye(BOARD, SIM_CAMERA, 15, np.random.default_rng(3), robot_noise=ROBOT)
    M = sim.T_base_tcp.copy()
    M[-2:, :3, 3] += [0.004, -0.003, 0.002]  # the board knocked 5.4 mm before the last two views
    out = calibrate_handeye_images(sim.views, M, SIM_CAMERA, holdout=False)
    assert out.outlier_views == ["view_13.png", "view_14.png"]
    assert out.result.verdict == "warning" and "the board moved" in out.result.reasons[0]
    assert out.result.metrics["n_views"] == 13
    clean = calibrate_handeye_images(sim.views, sim.T_base_tcp, SIM_CAMERA, holdout=False)
    assert clean.outlier_views == [] and "outlier_views" not in clean.result.estimate


def test_a_bad_robot_noise_option_is_refused():
    sim = simulate_handeye(BOARD, SIM_CAMERA, 4, np.random.default_rng(1))
    with pytest.raises(ValueError, match="robot_noise must be"):
        refine_reprojection("eye_in_hand", sim.T_base_tcp, sim.views, SIM_CAMERA, sim.X, sim.Y, robot_noise="guess")


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(0.0, 1e6, allow_nan=False), min_size=0, max_size=40),
    st.floats(0.0, 1e3, allow_nan=False),
)
def test_the_outlier_test_never_flags_many_views_or_few(d2, rms):
    d2 = np.array(d2)
    view_rms = np.full(len(d2), rms) + d2 * 1e-3
    flagged = moved_views(d2, view_rms)
    assert flagged.shape == d2.shape and flagged.dtype == bool
    assert flagged.sum() <= len(d2) // 3
    if len(d2) < 6:
        assert not flagged.any()
    if flagged.any():  # a flagged view's correction is beyond the median view's
        assert d2[flagged].min() > np.median(d2)


def test_a_robot_whose_own_error_limits_the_result_is_a_warning_and_a_moved_board_still_fails():
    """Robot poses off by 1.5 mm / 0.15 deg (an uncalibrated arm): the corners reproject beyond 2 px
    through them, but the board's predicted pose spreads only as far as a robot's error can take it:
    the result is usable, the reason names the robot. Boards far apart are still a failure."""
    sim = simulate_handeye(
        BOARD, SIM_CAMERA, 15, np.random.default_rng(21), robot_noise=RobotNoise(1.5e-3, np.radians(0.15))
    )
    r = calibrate_handeye_images(sim.views, sim.T_base_tcp, SIM_CAMERA, holdout=False).result
    assert r.metrics["rms_px"] > 2.0
    assert r.usable and any("robot's own pose accuracy" in x for x in r.reasons), r.reasons
    assert any("calibrate its kinematics" in a for a in r.advice)
    M = sim.T_base_tcp.copy()
    M[:, :3, 3] += np.random.default_rng(22).normal(scale=0.03, size=(len(M), 3))  # 30 mm per pose: no arm
    bad = calibrate_handeye_images(sim.views, M, SIM_CAMERA, holdout=False).result
    assert bad.verdict == "failed" and any("more than any robot's pose error" in x for x in bad.reasons), bad.reasons
