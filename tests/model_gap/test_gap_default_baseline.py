"""The default baseline is the full calibration the data identify; geometric terms never use up max_effects.

A real robot has geometric errors on every joint: the ``full`` scenario of the simulator gives it DH
errors of 0.1-0.5 mm and 0.1-1 mrad on every joint, a tracker 3.5 m away in an unknown frame and a
roughly known tool point. Without ``--calibrate`` the workflow calibrates the frame, the tool and the
identifiable joint geometry first (as ``vgr calibrate kinematics`` does), so the hidden effect is
what it names; the geometric candidates are absorbed by that calibration, not named.
"""

from __future__ import annotations

import pytest
from model_gap_helpers import case, families, run

from plugins.model_gap import analyse_gap
from plugins.model_gap.core import GapConfig, SelectionConfig
from plugins.sim.model_gap.simulate import make_case

pytestmark = pytest.mark.timeout(300)

GEOMETRIC = {"joint_offset", "link_length", "base_frame", "tool_offset", "robot_scale"}


def test_the_default_calibrates_the_joint_geometry_and_names_only_the_hidden_effect():
    _, res = run(case([("joint_compliance", "joint3")], scenario="full", seed=12))
    assert res.named == [("joint_compliance", "joint3")], res.reason
    assert res.verdict == "explained", res.reason
    cal = res.problem["calibration"]
    assert cal["levels"] == ["frame", "tool", "joints"] and cal["requested"] == "default"
    assert any(p.startswith("joint3.") for p in cal["parameters"]) and len(cal["parameters"]) >= 27
    absorbed = {c.name for c in res.iterations[0].scores if c.absorbed}
    assert absorbed >= GEOMETRIC  # calibrated, so never named and never counted as an effect
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms


def test_geometric_terms_do_not_use_up_max_effects():
    """With only the frame and the tool calibrated, a joint zero offset is named as an effect: it joins
    the model but does not count, so --max-effects 1 still leaves room for the backlash."""
    c = case([("joint_offset", "joint3"), ("backlash", "joint4")], seed=3)
    camp = make_case(c)
    cfg = GapConfig(SelectionConfig(cv_folds=4), max_effects=1)
    res = analyse_gap(camp.model, camp.data, noise_mm=0.05, calibrate=c.calibrate, config=cfg, families=families())
    assert sorted(res.named) == [("backlash", "joint4"), ("joint_offset", "joint3")], res.reason
    assert res.verdict == "explained", res.reason


def test_too_few_samples_for_the_joint_geometry_fall_back_to_frame_and_tool_and_say_so():
    c = case([], seed=4)
    camp = make_case(c)
    data = camp.data.subset(range(20))  # the joint geometry would need 23 with 5 folds, frame + tool 15
    res = analyse_gap(camp.model, data, noise_mm=0.05, families=families(), config=GapConfig())
    cal = res.problem["calibration"]
    assert cal["levels"] == ["frame", "tool"] and cal["requested"] == "default"
    assert cal["notes"][0].startswith("the joint geometry was not calibrated, only the measurement frame and the tool")
    assert "20 samples are too few" in cal["notes"][0]
