"""Gross errors: flying pixels (3-15 cm along their ray, at known places) are flagged, counted per
capture and left out, and the named effect and its coefficients do not change; the simulator's own
flying pixels (1-5 % of the pixels) are flagged to the pixel; without the screen they are not, and
the held-out error they leave is far above the noise."""

from __future__ import annotations

import numpy as np
import pytest
from depth_gap_helpers import add_flying_pixels

from plugins.model_gap.depth.catalog import effect_by_name
from plugins.model_gap.depth.workflow import DepthGapConfig, run_depth_gap
from plugins.sim.model_gap.depth_captures import simulate_captures

RADIAL = effect_by_name("radial_pattern")


def test_flying_pixels_are_flagged_per_capture_and_leave_the_named_effect_alone():
    clean = run_depth_gap(simulate_captures("radial_pattern", seed=5))
    caps = simulate_captures("radial_pattern", seed=5)
    injected = add_flying_pixels(caps, per_capture=120, seed=1)
    dirty = run_depth_gap(caps)
    assert dirty.named == clean.named == ["radial_pattern"], dirty.reason
    assert dirty.flagged_per_capture == injected  # every flying pixel, and no good one
    assert f"{sum(injected)} gross-error pixels left out" in dirty.reason
    assert dirty.final_fit.theta_of(RADIAL) == pytest.approx(clean.final_fit.theta_of(RADIAL), rel=0.05)
    assert dirty.final_cv.rms_mm == pytest.approx(clean.final_cv.rms_mm, rel=0.02)


@pytest.mark.parametrize("fraction", [0.01, 0.05])
def test_the_simulated_flying_pixels_are_all_flagged(fraction):
    caps = simulate_captures("wiggling", seed=2, outlier_fraction=fraction)
    result = run_depth_gap(caps)
    injected = [max(1, round(fraction * int(np.isfinite(f.depth).sum()))) for f in caps.frames]  # as _flying
    assert result.flagged_per_capture == injected
    assert result.named == ["wiggling"] and result.verdict == "explained", result.reason


def test_without_the_screen_flying_pixels_stay_in():
    caps = simulate_captures("wiggling", seed=2, outlier_fraction=0.03)
    result = run_depth_gap(caps, DepthGapConfig(outlier_alpha=0.0))
    assert result.screen.n_flagged == 0
    assert result.final_cv.rms_mm > 5.0  # flying pixels of 2-20 cm dominate: tens of times the 1 mm noise
