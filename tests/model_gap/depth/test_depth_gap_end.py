"""The honest end: range errors outside the catalog (a step in range, a sinusoid of another period
than the catalog's wiggle, a cubic pattern across the image), written into the simulated depth
images, leave structure the sign-flip tests find: the verdict is ``unexplained`` with where it is,
what to measure, and each added term's share; a stated noise far below the residuals is a gap too;
the effect limit reached with a candidate still eligible is ``unexplained``."""

from __future__ import annotations

import numpy as np
import pytest
from depth_gap_helpers import add_range_error

from plugins.model_gap.depth.data import SigmaLaw
from plugins.model_gap.depth.workflow import DepthGapConfig, run_depth_gap
from plugins.sim.model_gap.depth_captures import SIM_NOISE, simulate_captures


def step(r: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.where(r > 0.8, 2e-3, 0.0)  # a range-dependent step (a ToF's phase unwrapping slip)


def sine_031(r: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 1.5e-3 * np.sin(2 * np.pi * r / 0.31)  # a wiggle of another period than the catalog's 0.187 m


def cubic_x(r: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 3e-2 * x**3  # a per-pixel pattern of higher order than the catalog's quadratic


@pytest.mark.parametrize(
    ("error", "where"), [(step, "fixed in range"), (sine_031, "fixed in range"), (cubic_x, "fixed in the image")]
)
def test_an_error_outside_the_catalog_is_unexplained_with_where_and_the_shares(error, where):
    result = run_depth_gap(add_range_error(simulate_captures(None, seed=4), error))
    assert result.verdict == "unexplained", result.reason
    assert result.structure_after.p_value < 1e-3 and where in result.reason
    assert "capture the target" in result.reason  # what to measure next
    for a in result.added:
        assert 0.0 <= a.share <= 1.0 and a.dropped == (a.share < 0.3)


def test_the_cubic_pattern_keeps_the_polynomial_term_that_explains_most_of_it():
    result = run_depth_gap(add_range_error(simulate_captures(None, seed=4), cubic_x))
    kept = [a.label for a in result.kept]
    assert kept == ["polynomial_pattern"] and result.kept[0].share > 0.5, result.reason
    assert result.final_cv.rms_mm < 0.7 * result.baseline_cv.rms_mm


def test_a_stated_noise_far_below_the_residuals_is_a_gap():
    caps = simulate_captures(None, seed=4)
    caps.sigma = SigmaLaw(SIM_NOISE.sigma_const_m / 4, SIM_NOISE.sigma_quad_per_m / 4)  # 4x too optimistic
    result = run_depth_gap(caps)
    assert result.verdict == "unexplained" and "the stated noise" in result.reason, result.reason
    assert result.noise["rms_over_stated"] > 3.0


def test_the_effect_limit_with_a_candidate_still_eligible_is_unexplained():
    result = run_depth_gap(simulate_captures("range_bias", seed=4), DepthGapConfig(max_effects=0))
    assert result.verdict == "unexplained" and "--max-effects 0" in result.reason and result.added == []
