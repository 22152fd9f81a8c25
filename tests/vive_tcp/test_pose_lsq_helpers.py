"""pose_lsq helpers: covariance/rank, identifiability, residual tests, input checks."""

import numpy as np
import pytest
from hypothesis import strategies as st
from scipy.stats import chi2

from engine.transforms import exp_so3
from plugins.calibration.pose_lsq import (
    analyse_identifiability,
    as_rotation_stack,
    chi2_consistency,
    finite_array,
    looks_like_millimetres,
    marginal_covariance,
    robust_variance_factor,
    studentised_block_tests,
)

angle = st.floats(-3.0, 3.0, allow_nan=False)


def test_marginal_covariance_equals_inverse_block_and_detects_rank():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(40, 5)) * [1.0, 1e3, 1e-3, 2.0, 5.0]
    cov, rank = marginal_covariance(J, 3)
    assert rank == 5
    assert np.allclose(cov, np.linalg.inv(J.T @ J)[:3, :3], rtol=1e-8)
    J2 = np.hstack([J, J[:, :1] + J[:, 1:2] * 1e-3])  # exactly dependent column
    assert marginal_covariance(J2)[1] == 5


def test_identifiability_reports_the_null_combination():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(30, 2))
    J = np.column_stack([A[:, 0], A[:, 0], A[:, 1]])  # only a + b is determined
    ident = analyse_identifiability(J, ["a", "b", "c"], np.ones(3))
    assert ident.rank == 2 and not ident.full_rank
    v = ident.null_space[0]
    assert abs(abs(v[0]) - np.sqrt(0.5)) < 1e-9 and abs(v[0] + v[1]) < 1e-9 and abs(v[2]) < 1e-9
    assert "a" in ident.descriptions[0] and "b" in ident.descriptions[0]
    # a nuisance column that absorbs c's effect removes c from what the data determine
    ident2 = analyse_identifiability(J[:, [0, 2]], ["a", "c"], np.ones(2), J_nuisance=J[:, [2]])
    assert ident2.rank == 1


def test_studentised_test_flags_the_outlier_in_a_linear_fit():
    rng = np.random.default_rng(2)
    x = np.linspace(0, 1, 30)
    J = np.column_stack([np.ones_like(x), x])
    e = rng.normal(size=30)
    e[7] += 8.0
    r = e - J @ np.linalg.lstsq(J, e, rcond=None)[0]
    stats, dofs, p = studentised_block_tests(J, r, [np.array([i]) for i in range(30)])
    assert np.argmin(p) == 7 and p[7] < 1e-6
    assert np.all(dofs == 1)
    assert np.sum(p < 1e-3) == 1
    # the robust scale is about 1 for unit-variance residuals, about 9 when they are 3x larger
    assert 0.5 < robust_variance_factor(stats, dofs) < 2.0
    assert 5 < robust_variance_factor(stats * 9, dofs) < 16


def test_chi2_consistency():
    assert chi2_consistency(10.0, 10)[0] == 1.0
    assert chi2_consistency(100.0, 10)[1] < 1e-10
    assert abs(chi2_consistency(chi2.ppf(0.5, 7), 7)[1] - 0.5) < 1e-9


def test_input_checks():
    with pytest.raises(ValueError, match="NaN"):
        finite_array("x", [1.0, np.nan, 2.0])
    with pytest.raises(ValueError, match="shape"):
        finite_array("x", np.zeros((2, 4)), (None, 3))
    R = np.stack([np.eye(3), np.diag([1.0, 1.0, -1.0])])
    with pytest.raises(ValueError, match=r"\[1\] is not a rotation"):
        as_rotation_stack("R", R)
    R_round = np.round(exp_so3([0.3, -0.2, 0.1]), 5)[None]
    fixed, dev = as_rotation_stack("R", R_round)
    assert 1e-7 < dev < 1e-4 and np.allclose(fixed[0].T @ fixed[0], np.eye(3), atol=1e-12)
    assert looks_like_millimetres([[1200.0, 5.0, 3.0]], 5.0)
    assert not looks_like_millimetres([[1.2, 0.005, 0.3]], 5.0)
