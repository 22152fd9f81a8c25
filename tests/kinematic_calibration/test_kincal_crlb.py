"""Monte-Carlo: the calibration is efficient (errors at the Cramér-Rao bound) and its covariance honest.

30 trials of the same 60 UR5e poses with independent 0.05 mm noise. The reference ("identifiable
truth") is the calibration of the noise-free data; the CRLB ``C`` is ``(J^T J)^-1`` of the whitened
Jacobian there. Compared: the joint and tool parameters (the base parameters are offsets from the
per-trial initial frame, so they are not comparable across trials as numbers).

Every bound below is a quantile of the distribution the statistic has when the estimator is
efficient, at the trial count used (two-sided 99.9 %, so a correct solver fails about once in a
thousand seeds; the seeds are fixed):

* aggregate: each ``e^T C^-1 e`` is chi-square with ``p`` degrees of freedom, their sum over ``T``
  trials chi-square with ``T p`` (630 here: the mean normalised squared error scatters by 5.6 %
  and its bound is 1.196, a ratio of 1.094, so an estimator 1.1x above the CRLB, 1.21 in this
  measure, fails more often than not);
* per parameter: ``T (RMS / CRLB sigma)^2`` is chi-square with ``T``; none may exceed its 99.9 %
  quantile after Bonferroni's correction for ``p`` parameters;
* reported covariance (scaled by the residual variance, ``nu`` degrees of freedom): each
  ``e^T C_reported^-1 e / p`` is F(p, nu); their mean lies within 3.29 standard deviations of the F
  mean.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from plugins.calibration.kinematics import (
    KinematicCalibrationConfig,
    KinematicSamples,
    calibrate_kinematics,
)

from .kincal_sim import measure, nominal_model, random_poses, true_robot

TRIALS = 30
Z999 = float(stats.norm.ppf(0.9995))  # two-sided 99.9 %


def _values(out, names):
    v = dict(zip(out.model.param_names, out.model.param_values, strict=True))
    return np.array([v[n] for n in names])


@pytest.mark.slow
def test_identifiable_parameters_reach_the_crlb_and_covariance_is_calibrated():
    truth = true_robot("ur5e", seed=21)
    model = nominal_model("ur5e")
    q = random_poses(model, 60, seed=22)
    cfg = KinematicCalibrationConfig(holdout_fraction=0.0, trust_noise=True)
    clean = KinematicSamples(q, truth.fk(q)[:, :3, 3])
    ref = calibrate_kinematics(model, clean, config=cfg)
    assert ref.result.metrics["rms_after_mm"] < 1e-6  # the model family contains the truth
    names = [n for n in ref.result.param_names if not n.startswith("base.")]
    sel = [ref.result.param_names.index(n) for n in names]
    crlb = ref.result.covariance[np.ix_(sel, sel)]
    x_ref = _values(ref, names)
    errors, mahal_reported, nu = [], [], None
    for k in range(TRIALS):
        out = calibrate_kinematics(
            model, measure(truth, q, seed=100 + k), config=KinematicCalibrationConfig(holdout_fraction=0.0)
        )
        assert out.result.param_names == ref.result.param_names
        assert out.result.iterations <= 10
        e = _values(out, names) - x_ref
        errors.append(e)
        cov = out.result.covariance[np.ix_(sel, sel)]  # reported, with the estimated variance factor
        mahal_reported.append(e @ np.linalg.solve(cov, e) / len(names))
        nu = out.result.metrics["covariance_dof"]
    E = np.array(errors)
    p, T = len(names), TRIALS
    total = float(np.sum([e @ np.linalg.solve(crlb, e) for e in E]))
    ratio2 = np.mean(E**2, axis=0) / np.diag(crlb)
    print(f"\nCRLB check over {T} trials, {p} parameters: mean normalised squared error {total / (T * p):.3f}")
    print(
        f"RMS error / CRLB sigma per parameter: median {np.median(np.sqrt(ratio2)):.3f}, max {np.sqrt(ratio2.max()):.3f}"
    )
    print(f"reported covariance: mean e^T C^-1 e / p = {np.mean(mahal_reported):.3f} (nu = {nu:.0f})")
    # aggregate: sum of T chi2(p) terms
    assert stats.chi2.ppf(0.0005, T * p) <= total <= stats.chi2.ppf(0.9995, T * p)
    # every single parameter: T ratio^2 ~ chi2(T), Bonferroni over p
    assert np.all(T * ratio2 <= stats.chi2.ppf(1.0 - 0.001 / p, T))
    # reported covariance: mean of T F(p, nu) terms
    assert nu == 3 * len(q) - len(ref.result.param_names)
    f_mean, f_var = stats.f.stats(p, nu, moments="mv")
    assert abs(np.mean(mahal_reported) - f_mean) <= Z999 * np.sqrt(f_var / T)
    assert np.sqrt(np.diag(crlb)).max() < 1e-3  # every identified parameter is determined to < 1 mm / 1 mrad
