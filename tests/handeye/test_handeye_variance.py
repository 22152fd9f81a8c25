"""Confidence regions of an estimated-noise covariance: Helmert's matrix and Kenward-Roger."""

import numpy as np
import pytest
from scipy import stats

from plugins.calibration.handeye import NoiseModel, calibrate_hand_eye
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.ml_model import EivModel
from plugins.calibration.handeye.variance import group_rows, helmert_matrix, kenward_roger, kenward_roger_dof
from plugins.calibration.result import CalibrationResult

NOISE = NoiseModel.isotropic(robot_deg=0.02, robot_mm=0.1, camera_deg=0.1, camera_mm=0.5)


def _model(noise: NoiseModel, n: int = 8, seed: int = 40):
    rng = np.random.default_rng(seed)
    truth = sim.viewing_scene(rng, n, "eye_in_hand")
    meas = sim.add_noise(truth, noise, rng)
    model = EivModel("eye_in_hand", meas.T_base_tcp, meas.T_cam_target, noise, truth.X, truth.Y)
    return model, model.state(np.zeros(model.n_params), jacobian=True)


def _dense(model, st, w):
    """Full-parameter whitened Jacobian over the used rows, and each group's row selector."""
    r = model.rows_per_sample
    J = model.jacobian_matrix(np.zeros(model.n_params), np.sqrt(w), as_sparse=False)
    rows = np.repeat(w > 0, r)
    J = J[rows][:, np.abs(J[rows]).sum(axis=0) > 0]
    sel = [np.tile(np.isin(np.arange(r), np.arange(r)[g]), int(w.sum())) for g in group_rows(model)]
    return J, sel


@pytest.mark.parametrize("robot_exact", [False, True])
def test_helmert_matrix_matches_the_full_residual_projector(robot_exact):
    noise = NoiseModel.isotropic(0.0, 0.0, 0.1, 0.5) if robot_exact else NOISE
    model, st = _model(noise)
    w = np.ones(model.n)
    w[2] = 0.0  # an outlier left out
    H, B, S = helmert_matrix(model, st, w)
    # brute force: R = I - J J^+ over the used rows, H_gh = sum of R^2 over group g rows x group h rows
    r = model.rows_per_sample
    J, sel = _dense(model, st, w)
    R = np.eye(J.shape[0]) - J @ np.linalg.pinv(J)
    H_brute = np.array([[np.sum(R[np.ix_(a, b)] ** 2) for b in sel] for a in sel])
    assert np.allclose(H, H_brute, rtol=0, atol=1e-9)
    # row sums are the groups' redundancy numbers, which add up to the degrees of freedom
    h = model.hat_diagonal(st, w)[w > 0]
    assert H.sum(axis=1) == pytest.approx([(1 - h[:, g]).sum() for g in group_rows(model)], abs=1e-9)
    assert H.sum() == pytest.approx(r * w.sum() - 12 - (6 * w.sum() if not robot_exact else 0), abs=1e-9)
    assert sum(B) == pytest.approx(S, rel=1e-12, abs=1e-6)


@pytest.mark.parametrize("robot_exact", [False, True])
def test_kenward_roger_covariance_matches_the_dense_formula(robot_exact):
    """Phi_A = Phi + 2 Phi [sum W_gg B_g - sum W_gh B_g Phi B_h] Phi over ALL parameters (nuisance
    robot poses included), compared in the (X, Y) block with the block-structured computation."""
    noise = NoiseModel.isotropic(0.0, 0.0, 0.1, 0.5) if robot_exact else NOISE
    model, st = _model(noise)
    w = np.ones(model.n)
    J, sel = _dense(model, st, w)
    Phi = np.linalg.inv(J.T @ J)
    R = np.eye(J.shape[0]) - J @ Phi @ J.T
    H = np.array([[np.sum(R[np.ix_(a, b)] ** 2) for b in sel] for a in sel])
    est = np.ones(len(sel), dtype=bool)
    est[0] = False  # one group kept at its prior: it carries no variance
    W = np.zeros_like(H)
    W[np.ix_(est, est)] = 2.0 * np.linalg.inv(H[np.ix_(est, est)])
    B = [J[a].T @ J[a] for a in sel]
    middle = sum(W[g, g] * B[g] for g in range(len(B))) - sum(
        W[g, h] * B[g] @ Phi @ B[h] for g in range(len(B)) for h in range(len(B))
    )
    phi_a = Phi + 2.0 * Phi @ middle @ Phi
    kr = kenward_roger(model, st, w, est, [slice(0, 6), slice(0, 12)])
    assert np.allclose(kr.covariance, phi_a[:12, :12], rtol=1e-8, atol=1e-12 * np.abs(Phi[:12, :12]).max())
    # the adjustment widens X's covariance (on average over its whitened directions)
    assert np.trace(np.linalg.solve(Phi[:6, :6], kr.covariance[:6, :6])) / 6 > 1.0
    for dof, scale in zip(kr.dof, kr.f_scale, strict=True):
        assert dof > 4 and 0.8 < scale <= 1.0 + 1e-12


@pytest.mark.parametrize("k", [1, 6, 12])
def test_kenward_roger_is_exact_for_one_variance_factor(k):
    """One variance factor with nu degrees of freedom: KR gives exactly F(k, nu) (m = nu, lambda = 1)."""
    rng = np.random.default_rng(k)
    A = rng.normal(size=(k, k))
    C = A @ A.T + k * np.eye(k)
    for nu in (8.0, 40.0, 400.0):
        m, scale = kenward_roger_dof(np.linalg.inv(C), [C], np.array([[2.0 / nu]]))
        assert m == pytest.approx(nu, rel=1e-9) and scale == pytest.approx(1.0, rel=1e-9)
    assert kenward_roger_dof(np.linalg.inv(C), [C], np.zeros((1, 1))) == (float("inf"), 1.0)


def test_results_state_their_confidence_region():
    rng = np.random.default_rng(41)
    meas = sim.add_noise(sim.viewing_scene(rng, 15, "eye_in_hand"), NOISE, rng)
    declared = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, setup="eye_in_hand", noise=NOISE)
    assert declared.metrics["covariance_factor"] == 1.0  # the declared noise fits: known covariance
    assert "covariance_dof" not in declared.metrics
    assert declared.confidence_threshold(6) == pytest.approx(stats.chi2.ppf(0.95, 6))
    estimated = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, setup="eye_in_hand")
    m = estimated.metrics
    nu, scale = m["covariance_dof"], m["covariance_f_scale"]
    assert 10 < nu <= m["dof"] and 0.8 < scale <= 1.0
    assert m["covariance_kr_inflation"] > 1.0
    assert estimated.confidence_threshold(6) == pytest.approx(6 * stats.f.ppf(0.95, 6, nu) / scale)
    assert estimated.confidence_threshold(6) > stats.chi2.ppf(0.95, 6)
    nu_xy, scale_xy = m["covariance_dof_xy"], m["covariance_f_scale_xy"]
    thr_xy = estimated.confidence_threshold(12, dof=nu_xy, f_scale=scale_xy)
    assert thr_xy == pytest.approx(12 * stats.f.ppf(0.95, 12, nu_xy) / scale_xy)
    # the JSON form keeps it
    back = CalibrationResult.from_dict(__import__("json").loads(estimated.to_json()))
    assert back.confidence_threshold(6) == pytest.approx(estimated.confidence_threshold(6))


def test_a_scaled_declared_noise_uses_the_variance_factor_dof():
    rng = np.random.default_rng(42)
    truth = sim.viewing_scene(rng, 15, "eye_in_hand")
    meas = sim.add_noise(truth, NoiseModel.isotropic(0.04, 0.2, 0.2, 1.0), rng)  # twice the declared noise
    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, setup="eye_in_hand", noise=NOISE)
    assert res.metrics["covariance_factor"] != 1.0
    assert res.metrics["covariance_dof"] == res.metrics["dof"] and "covariance_f_scale" not in res.metrics
    assert res.confidence_threshold(6) == pytest.approx(6 * stats.f.ppf(0.95, 6, res.metrics["dof"]))
