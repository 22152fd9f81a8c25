"""Vive desk calibration (seed 001) against simulated ground truth: accuracy in mm / deg,
covariance, identifiability verdicts, outliers, the seed's checks and acceptance test."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from engine.transforms import T_from_Rt, inv, log_so3, pose_error
from plugins.calibration.result import CalibrationResult
from plugins.calibration.vive_desk import (
    DesktopTcpConverter,
    TrackerTcpPrior,
    ViveDeskData,
    ViveNoiseModel,
    calibrate_vive_desk,
)
from plugins.calibration.vive_desk.initial import initial_estimate, seed_step1_T_base_desktop
from plugins.calibration.vive_desk.model import DeskProblem
from plugins.calibration.vive_desk.realtime import desktop_tcp
from plugins.calibration.vive_desk.seed_baseline import seed_calibrate
from plugins.calibration.vive_desk.simulate import (
    SEED_POINTS_3,
    SEED_POINTS_4,
    simulate_contacts,
    tilted_fixture_orientations,
)
from plugins.calibration.vive_desk.solver import cramer_rao_bound

GOOD_SCATTER = np.radians(0.2)  # per axis: ~0.5 deg RMS pairwise, a good fixture (seed 001)


def multi_orientation(points=SEED_POINTS_4, tilt=30.0):
    R = tilted_fixture_orientations(tilt)
    return np.vstack([points] * 3), np.repeat(R, len(points), axis=0)


def errors_mm_deg(res, sim):
    e_bd = pose_error(res.estimate["T_base_desktop"], sim.T_base_desktop)
    e_kc = pose_error(res.estimate["T_tracker_tcp"], sim.T_tracker_tcp)
    return e_bd[0] * 1e3, np.degrees(e_bd[1]), e_kc[0] * 1e3, np.degrees(e_kc[1])


def error12(res, sim):
    e = np.zeros(12)
    for k, (name, T) in enumerate((("T_base_desktop", sim.T_base_desktop), ("T_tracker_tcp", sim.T_tracker_tcp))):
        A = res.estimate[name]
        e[6 * k : 6 * k + 3] = A[:3, 3] - T[:3, 3]
        e[6 * k + 3 : 6 * k + 6] = log_so3(A[:3, :3] @ T[:3, :3].T)
    return e


def test_noise_free_contacts_recover_the_truth_exactly():
    pts, Rf = multi_orientation()
    sim = simulate_contacts(
        pts,
        seed=1,
        R_desktop_tcp=Rf,
        tracker_position_sigma_m=0,
        tracker_rotation_sigma_rad=0,
        fixture_scatter_rad=0,
        noise_model=ViveNoiseModel(),
    )
    res = calibrate_vive_desk(sim.data)
    bd_mm, bd_deg, kc_mm, kc_deg = errors_mm_deg(res, sim)
    assert bd_mm < 1e-6 and kc_mm < 1e-6 and bd_deg < 1e-7 and kc_deg < 1e-7
    # usable; a "weakly determined" warning may remain: the noise model (0.5 mm jitter) predicts
    # ~1.1 mm RMS for the translations with 12 contacts even if this draw happens to be exact
    assert res.usable and not any("[degenerate]" in r or "[failed]" in r for r in res.reasons), res.reasons
    assert res.metrics["design_rank"] == 12
    assert np.max(np.abs(res.residuals)) < 1e-9


def test_multi_orientation_accuracy_matches_its_covariance():
    """12 contacts, Vive jitter 0.5 mm / 0.1 deg, good fixture: errors ~1 mm / ~0.15 deg, inside
    the reported 99.9 % ellipsoid; predicted RMS within 10 % of the Cramér–Rao bound."""
    pts, Rf = multi_orientation()
    sim = simulate_contacts(pts, seed=7, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER)
    res = calibrate_vive_desk(sim.data)
    assert res.usable, res.reasons
    bd_mm, bd_deg, kc_mm, kc_deg = errors_mm_deg(res, sim)
    assert bd_mm < 3.0 and kc_mm < 3.0 and bd_deg < 0.4 and kc_deg < 0.5
    e = error12(res, sim)
    assert e @ np.linalg.solve(res.covariance, e) < chi2.ppf(0.999, 12)
    crlb, rank = cramer_rao_bound(sim.data, sim.T_base_desktop, sim.T_tracker_tcp)
    assert rank == 12 + 3 * sim.data.n
    assert np.allclose(np.sqrt(np.diag(res.covariance)), np.sqrt(np.diag(crlb)), rtol=0.1)
    assert res.residuals.shape == (12, 6) and res.outliers.shape == (12,) and not res.outliers.any()
    assert len(res.param_names) == 12 == res.covariance.shape[0]


@pytest.mark.slow
def test_monte_carlo_rms_near_crlb_and_covariance_calibrated():
    """40 trials: RMS error / CRLB <= 1.15 for each block, truth inside the 95 % ellipsoid in
    >= 85 % of trials (the benchmark runs 200 trials with the 1.05 target)."""
    pts, Rf = multi_orientation()
    errs, inside = [], 0
    for k in range(40):
        sim = simulate_contacts(pts, seed=100 + k, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER)
        res = calibrate_vive_desk(sim.data)
        e = error12(res, sim)
        errs.append(e)
        inside += e @ np.linalg.solve(res.covariance, e) < chi2.ppf(0.95, 12)
    crlb, _ = cramer_rao_bound(sim.data, sim.T_base_desktop, sim.T_tracker_tcp)
    E = np.array(errs)
    for s in (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)):
        ratio = np.sqrt(np.mean(np.sum(E[:, s] ** 2, 1))) / np.sqrt(np.trace(crlb[s, s]))
        assert ratio < 1.15, (s, ratio)
    assert inside / 40 >= 0.85


def test_single_fixture_orientation_is_degenerate_with_advice_but_tcp_at_calibration_is_right():
    sim = simulate_contacts(SEED_POINTS_3, seed=3, fixture_scatter_rad=GOOD_SCATTER)
    res = calibrate_vive_desk(sim.data)
    assert res.verdict == "degenerate" and not res.usable
    text = " ".join(res.reasons)
    assert "lever arm not identifiable" in text
    assert any("fixture orientations tilted about two different axes" in a for a in res.advice)
    assert res.metrics["design_rank"] == 9
    # the identifiable part: TCP pose in the desk frame at the calibration orientation
    T_cal = sim.T_base_tracker_true[0]
    est = desktop_tcp(T_cal, res.estimate["T_base_desktop"], res.estimate["T_tracker_tcp"])
    true = desktop_tcp(T_cal, sim.T_base_desktop, sim.T_tracker_tcp)
    d_mm, d_rad = pose_error(est, true)
    assert d_mm * 1e3 < 2.5 and np.degrees(d_rad) < 0.8
    # ...and 20 deg away from it the unidentified lever arm shows (~cm, 10x the noise floor)
    T_tilt = sim.T_base_desktop @ T_from_Rt(Rotation.from_euler("x", 20, degrees=True).as_matrix(),
                                            [0.1, -0.1, 0.12]) @ inv(sim.T_tracker_tcp)  # fmt: skip
    est = desktop_tcp(T_tilt, res.estimate["T_base_desktop"], res.estimate["T_tracker_tcp"])
    true = desktop_tcp(T_tilt, sim.T_base_desktop, sim.T_tracker_tcp)
    assert pose_error(est, true)[0] > 0.005
    with pytest.raises(ValueError, match="degenerate"):
        DesktopTcpConverter.from_result(res)


def test_cad_prior_makes_a_single_orientation_usable():
    sim = simulate_contacts(SEED_POINTS_3, seed=3, fixture_scatter_rad=GOOD_SCATTER)
    T_cad = sim.T_tracker_tcp.copy()
    T_cad[:3, 3] += [0.0005, -0.0008, 0.0003]
    res = calibrate_vive_desk(sim.data, prior=TrackerTcpPrior(T_cad, sigma_position_m=1e-3))
    assert res.metrics["design_rank"] == 12
    assert res.verdict in ("ok", "warning") and "lever arm" not in " ".join(res.reasons)
    bd_mm, bd_deg, kc_mm, _kc_deg = errors_mm_deg(res, sim)
    assert kc_mm < 2.0 and bd_mm < 4.0 and bd_deg < 1.0


def test_two_orientations_leave_one_direction_three_fix_all():
    R = tilted_fixture_orientations(30.0)
    pts2 = np.vstack([SEED_POINTS_3] * 2)
    sim2 = simulate_contacts(pts2, seed=4, R_desktop_tcp=np.repeat(R[:2], 3, axis=0), fixture_scatter_rad=GOOD_SCATTER)
    res2 = calibrate_vive_desk(sim2.data)
    assert res2.verdict == "degenerate" and res2.metrics["design_rank"] == 11
    assert any("different axis" in a for a in res2.advice)
    pts3, Rf3 = multi_orientation(SEED_POINTS_3)
    res3 = calibrate_vive_desk(
        simulate_contacts(pts3, seed=4, R_desktop_tcp=Rf3, fixture_scatter_rad=GOOD_SCATTER).data
    )
    assert res3.metrics["design_rank"] == 12 and res3.usable


def test_free_orientation_pivot_contacts_make_the_lever_arm_identifiable():
    """Seed layout at the fixture orientation plus 6 pivot contacts (tip in a socket at P1, tool
    turned freely up to 35 deg, orientation unknown to the solver)."""
    rng = np.random.default_rng(5)
    R_piv = [Rotation.from_rotvec(rng.normal(size=3) * 0.35).as_matrix() for _ in range(6)]
    pts = np.vstack([SEED_POINTS_3, np.zeros((6, 3))])
    Rf = np.stack([np.eye(3)] * 3 + R_piv)
    known = np.array([True] * 3 + [False] * 6)
    sim = simulate_contacts(pts, seed=5, R_desktop_tcp=Rf, orientation_known=known, fixture_scatter_rad=GOOD_SCATTER)
    res = calibrate_vive_desk(sim.data)
    assert res.metrics["design_rank"] == 12, res.reasons
    assert res.usable, res.reasons
    bd_mm, bd_deg, kc_mm, kc_deg = errors_mm_deg(res, sim)
    assert kc_mm < 3.0 and bd_mm < 4.0 and bd_deg < 1.0 and kc_deg < 1.0


def test_collinear_points_are_degenerate_with_one_orientation_and_a_warning_with_three():
    P = np.array([[0, 0, 0], [0.15, 0, 0], [0.3, 0, 0], [0.45, 0, 0]])
    res1 = calibrate_vive_desk(
        simulate_contacts(P, seed=6, fixture_scatter_rad=GOOD_SCATTER).data,
        prior=TrackerTcpPrior(np.eye(4), 1.0),  # a (loose) prior so that only the line is the issue
    )
    assert res1.verdict == "degenerate"
    assert any("collinear" in r and r.startswith("[degenerate]") for r in res1.reasons)
    assert any("off the line" in a for a in res1.advice)
    # with three fixture orientations the relative rotations pin the desk's roll about the line
    pts = np.vstack([P] * 3)
    Rf = np.repeat(tilted_fixture_orientations(), 4, axis=0)
    res3 = calibrate_vive_desk(simulate_contacts(pts, seed=6, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER).data)
    assert res3.metrics["design_rank"] == 12
    assert any("collinear" in r and r.startswith("[warning]") for r in res3.reasons)


def test_points_closer_than_10_cm_warn():
    P = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.2, 0], [0.2, 0.2, 0]])
    pts = np.vstack([P] * 3)
    Rf = np.repeat(tilted_fixture_orientations(), 4, axis=0)
    res = calibrate_vive_desk(simulate_contacts(pts, seed=6, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER).data)
    assert any("50 mm apart" in r and r.startswith("[warning]") for r in res.reasons)
    assert any("10 cm" in a for a in res.advice)


@pytest.mark.parametrize(
    ("scatter_deg", "level", "word"),
    [
        (0.3, "info", "excellent"),
        (0.8, "info", "good"),
        (1.5, "warning", "large"),
        (3.0, "failed", "not reliable"),
    ],
)
def test_pose_consistency_bands_follow_the_seed(scatter_deg, level, word):
    """Tracker orientations at P2 and P3 differ from P1 by the given angle (seed 001's check)."""
    sim = simulate_contacts(SEED_POINTS_3, seed=8, fixture_scatter_rad=0.0, tracker_rotation_sigma_rad=1e-9)
    T = sim.data.T_base_tracker.copy()
    a = np.radians(scatter_deg)
    T[1, :3, :3] = T[1, :3, :3] @ Rotation.from_rotvec([a, 0, 0]).as_matrix()
    T[2, :3, :3] = T[2, :3, :3] @ Rotation.from_rotvec([0, a / 2, 0]).as_matrix()
    data = ViveDeskData.from_contacts(sim.data.desk_points, T, noise=sim.data.noise)
    res = calibrate_vive_desk(data)
    msg = next(r for r in res.reasons if "pose consistency" in r)
    assert msg.startswith(f"[{level}]") and word in msg
    assert res.metrics["pose_consistency_max_deg"] == pytest.approx(scatter_deg, rel=0.2)


def test_misplaced_contact_is_flagged_and_fails_the_seed_acceptance():
    pts, Rf = multi_orientation()
    sim = simulate_contacts(pts, seed=9, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER)
    wrong = sim.data.desk_points.copy()
    wrong[5] += [0.006, 0.0, 0.0]  # the user put the tool 6 mm off the marked point
    data = ViveDeskData.from_contacts(
        wrong, sim.data.T_base_tracker, R_desktop_tcp=sim.data.R_desktop_tcp, noise=sim.data.noise
    )
    res = calibrate_vive_desk(data)
    assert res.outliers[5] and res.outliers.sum() == 1
    assert any("P6" in a for a in res.advice)
    assert res.verdict == "failed" and any("acceptance not met" in r for r in res.reasons)


def test_seed_acceptance_fails_with_hand_held_scatter():
    pts, Rf = multi_orientation()
    sim = simulate_contacts(pts, seed=10, R_desktop_tcp=Rf, fixture_scatter_rad=np.radians(2.0))
    res = calibrate_vive_desk(sim.data)
    assert res.verdict == "failed"
    assert any("acceptance not met" in r for r in res.reasons)
    assert res.metrics["mean_rotation_error_deg"] > 0.5


def test_initialisers_and_seed_baseline():
    """vgr's exact start is within a few mm / tenths of a degree; the literal seed step 1 assumes
    the tracker z axis is the desk normal and P1->P2 is desk x, so it is far off with a tilted
    tracker, and vgr from the literal start still converges on the identifiable design."""
    pts, Rf = multi_orientation()
    sim = simulate_contacts(pts, seed=11, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER)
    T_BD0, T_KC0 = initial_estimate(sim.data)
    assert pose_error(T_BD0, sim.T_base_desktop)[0] < 0.01
    assert np.degrees(pose_error(T_BD0, sim.T_base_desktop)[1]) < 1.0
    assert np.degrees(pose_error(T_KC0, sim.T_tracker_tcp)[1]) < 1.0
    T_seed = seed_step1_T_base_desktop(sim.data.T_base_tracker)
    assert np.allclose(T_seed[:3, 3], sim.data.T_base_tracker[:, :3, 3].mean(0))
    assert np.degrees(pose_error(T_seed, sim.T_base_desktop)[1]) > 20.0
    res_exact = calibrate_vive_desk(sim.data)
    sr = seed_calibrate(sim.data, T_base_desktop0=T_BD0, T_tracker_tcp0=T_KC0)
    # same data: the seed's fixed weights are a (slightly) different estimator, both near truth
    assert pose_error(sr.T_base_desktop, sim.T_base_desktop)[0] < 0.005
    assert pose_error(res_exact.estimate["T_base_desktop"], sr.T_base_desktop)[0] < 0.003


def test_model_jacobian_matches_finite_differences():
    pts, Rf = multi_orientation()
    known = np.ones(len(pts), bool)
    known[4] = False
    sim = simulate_contacts(pts, seed=12, R_desktop_tcp=Rf, orientation_known=known, fixture_scatter_rad=np.radians(1))
    rng = np.random.default_rng(0)
    T_BD0 = sim.T_base_desktop @ T_from_Rt(Rotation.from_rotvec(rng.normal(size=3) * 0.1).as_matrix(), [0.01, 0, 0])
    prior = TrackerTcpPrior(sim.T_tracker_tcp, 2e-3, np.radians(1.0))
    prob = DeskProblem(sim.data, T_BD0, sim.T_tracker_tcp, sim.data.R_desktop_tcp, prior)
    x = rng.normal(scale=0.2, size=prob.n_params)
    _, J = prob.residual_and_jacobian(x)
    Jn = np.zeros_like(J)
    for k in range(x.size):
        d = np.zeros_like(x)
        d[k] = 1e-6
        Jn[:, k] = (prob.residual(x + d) - prob.residual(x - d)) / 2e-6
    assert np.max(np.abs(J - Jn)) < 1e-5 * np.max(np.abs(J))


def test_result_round_trips_through_json_and_drives_the_converter():
    pts, Rf = multi_orientation()
    sim = simulate_contacts(pts, seed=13, R_desktop_tcp=Rf, fixture_scatter_rad=GOOD_SCATTER)
    res = calibrate_vive_desk(sim.data)
    back = CalibrationResult.from_dict(__import__("json").loads(res.to_json()))
    assert back.verdict == res.verdict and np.allclose(back.covariance, res.covariance)
    conv = DesktopTcpConverter.from_result(back)
    out = conv.convert(sim.data.T_base_tracker[0])
    est = res.estimate
    expected = desktop_tcp(sim.data.T_base_tracker[0], est["T_base_desktop"], est["T_tracker_tcp"])
    assert np.allclose(out.T_desktop_tcp, expected)
    assert out.position_std_m is not None and np.all(out.position_std_m < 2e-3)


def test_noise_model_is_validated():
    with pytest.raises(ValueError, match="must be > 0"):
        ViveNoiseModel(tracker_position_sigma_m=0.0)
    with pytest.raises(ValueError, match="finite"):
        ViveNoiseModel(fixture_rotation_sigma_rad=float("nan"))
