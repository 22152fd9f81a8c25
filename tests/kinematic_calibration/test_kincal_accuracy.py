"""Kinematic calibration on simulated UR5e / IRB 120 data: convergence, held-out accuracy, identifiability.

Truth: random errors of 0.2 mm / 0.2 mrad (one sigma) on every DH parameter (theta, d, a, alpha and
Hayati beta), an unknown tracker frame 1.5 m away, an unknown tool point ~4 cm from the nominal one;
0.05 mm noise per axis.

"Held-out RMS at the noise floor" is tested against its expected value for a correct model,
``sqrt(3 sigma^2 + tr(A C A^T) / n_h)`` with the true sigma (``expected_holdout_rms``; about
``sqrt(3) sigma sqrt(1 + p/n)``: the fitted model's own uncertainty adds to the new noise), within
the two-sided 99.9 % band of ``(RMS / expected)^2 ~ chi2(dof) / dof`` (Satterthwaite dof).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from plugins.calibration.kinematics import (
    KinematicCalibrationConfig,
    calibrate_kinematics,
    expected_holdout_rms,
    format_table,
)
from plugins.calibration.kinematics.report import plot_convergence
from plugins.robot.model_file import robot_model_from_dict

from .kincal_sim import NOISE_M, measure, nominal_model, random_poses, true_robot


def assert_holdout_at_noise_floor(out, hold) -> float:
    """Held-out RMS against its expectation with the true noise; returns expected / noise floor."""
    m = out.result.metrics
    s2 = (m["sigma_position_mm"] / (NOISE_M * 1e3)) ** 2  # the calibration's variance factor
    expected, dof = expected_holdout_rms(out.model, hold, out.result.param_names, out.result.covariance / s2, NOISE_M)
    ratio2 = (m["holdout_rms_after_mm"] / (expected * 1e3)) ** 2
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], dof) / dof
    assert lo <= ratio2 <= hi, (np.sqrt(ratio2), np.sqrt(lo), np.sqrt(hi))
    # the library's own expectation is the same with its noise estimate
    assert m["holdout_rms_expected_mm"] == pytest.approx(np.sqrt(s2) * expected * 1e3, rel=1e-9)
    return expected / (np.sqrt(3) * NOISE_M)


@pytest.fixture(scope="module")
def ur5e_data():
    truth = true_robot("ur5e", seed=1)
    model = nominal_model("ur5e")
    cal = measure(truth, random_poses(model, 150, seed=2), seed=3)
    hold = measure(truth, random_poses(model, 200, seed=4), seed=5)
    return truth, model, cal, hold


@pytest.mark.parametrize("conv", ["dh", "mdh", "poe"])
def test_ur5e_converges_to_the_noise_floor(ur5e_data, conv, tmp_path):
    truth, model, cal, hold = ur5e_data
    out = calibrate_kinematics(
        model,
        cal,
        holdout=hold,
        config=KinematicCalibrationConfig(parameterisation=conv),
    )
    plot_convergence(out, tmp_path / "c.png")
    res = out.result
    assert res.verdict == "ok", res.reasons
    assert res.iterations <= 10
    assert len(res.param_names) == 27  # 4n + 6 - 3: tool orientation is invisible to a point measurement
    held = out.table[1]
    assert held["before"]["rms_mm"] > 0.3  # the nominal model is visibly wrong ...
    # ... the calibrated one is at the noise floor, raised by about sqrt(1 + p/n) for p fitted
    # parameters and n residuals (27 and 450: 1.03)
    above_floor = assert_holdout_at_noise_floor(out, hold)
    assert above_floor == pytest.approx(np.sqrt(1 + 27 / cal.positions.size), rel=0.01)
    # against the noise-free truth: the remaining model error is well below the noise
    q = hold.q
    model_err = np.linalg.norm(out.model.fk(q)[:, :3, 3] - truth.fk(q)[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(model_err**2)) < 0.5 * NOISE_M * np.sqrt(3)
    assert (tmp_path / "c.png").stat().st_size > 10_000
    assert "held-out" in format_table(out)


def test_parameterisations_agree(ur5e_data):
    _, model, cal, hold = ur5e_data
    preds = []
    for conv in ("dh", "mdh", "poe"):
        out = calibrate_kinematics(model, cal, holdout=hold, config=KinematicCalibrationConfig(parameterisation=conv))
        preds.append(out.model.fk(hold.q)[:, :3, 3])
    assert np.abs(preds[0] - preds[1]).max() < 1e-6
    assert np.abs(preds[0] - preds[2]).max() < 1e-6


def test_full_pose_data_identifies_4n_plus_6_parameters():
    truth = true_robot("ur5e", seed=6)
    model = nominal_model("ur5e")
    cal = measure(truth, random_poses(model, 80, 7), 8, rot_noise_rad=1e-4)
    hold = measure(truth, random_poses(model, 80, 9), 10, rot_noise_rad=1e-4)
    out = calibrate_kinematics(model, cal, holdout=hold)
    assert out.result.verdict == "ok", out.result.reasons
    assert len(out.result.param_names) == 30  # complete, minimal: 4 per revolute joint + 6
    assert out.result.iterations <= 10
    assert_holdout_at_noise_floor(out, hold)
    assert out.table[1]["after"]["rms_rot_deg"] < 2 * np.degrees(1e-4) * np.sqrt(3)


def test_irb120_position_calibration():
    truth = true_robot("abb_irb120", seed=11)
    model = nominal_model("abb_irb120")
    cal = measure(truth, random_poses(model, 120, 12), 13)
    hold = measure(truth, random_poses(model, 120, 14), 15)
    out = calibrate_kinematics(model, cal, holdout=hold)
    assert out.result.verdict == "ok" and out.result.iterations <= 10
    assert_holdout_at_noise_floor(out, hold)


def test_identifiability_names_the_structural_redundancies(ur5e_data):
    _, model, cal, hold = ur5e_data
    out = calibrate_kinematics(model, cal, holdout=hold)
    ident = out.identifiability
    # parallel joints 2, 3, 4: their d offsets slide along the common direction, only one survives
    assert "joint2.d" in ident.kept and "joint3.d" in ident.dropped and "joint4.d" in ident.dropped
    assert ident.confounded_with["joint3.d"][0][0] == "joint2.d"
    # with an unknown tracker frame, joint 1's zero and height are the frame's rotation and height
    assert ident.confounded_with["joint1.theta"][0] == ("base.rz", pytest.approx(1.0))
    assert ident.confounded_with["joint1.d"][0] == ("base.tz", pytest.approx(1.0))
    assert out.structural.kept == ident.kept  # random poses excite everything that can be excited
    assert ident.observability_o1 > 0 and np.isfinite(ident.condition_number)
    assert any("not identifiable" in r for r in out.result.reasons)


def test_result_is_complete_and_serialisable(ur5e_data):
    _, model, cal, hold = ur5e_data
    out = calibrate_kinematics(model, cal, holdout=hold)
    res = out.result
    assert res.kind == "kinematic" and res.usable
    assert res.covariance.shape == (27, 27) and np.all(np.linalg.eigvalsh(res.covariance) > 0)
    assert res.residuals.shape == (cal.n_samples, 3) and res.outliers.shape == (cal.n_samples,)
    assert not res.outliers.any()
    assert set(res.std()) == set(res.param_names)
    rebuilt = robot_model_from_dict(res.estimate["model_file"])
    assert np.abs(rebuilt.fk(hold.q) - out.model.fk(hold.q)).max() < 1e-12
    assert np.allclose(res.estimate["T_meas_base"], out.model.T_world_base)
    text = res.to_json()
    assert "holdout_rms_after_mm" in text
