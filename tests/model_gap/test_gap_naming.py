"""The workflow names the hidden effect and its place, names nothing in pure noise, closes the gap.

Hidden-effect datasets from the simulated cell (:mod:`plugins.sim.model_gap.simulate`): the
effect is known only to the test. UR5e, 160 samples, 0.05 mm noise per axis; "high" hides an effect
whose uncalibratable part has a 3-D RMS of 0.15 mm (the noise alone: 0.087 mm), "low" 0.05 mm.
"""

from __future__ import annotations

import numpy as np
import pytest
from model_gap_helpers import case, families, run

from plugins.model_gap import analyse_gap
from plugins.model_gap.core import GapConfig, SelectionConfig
from plugins.sim.model_gap.simulate import BOTH_SCENARIOS, KNOWN_FRAME_EFFECTS, make_case

pytestmark = pytest.mark.timeout(300)

SCALES = ["depth_scale@camera", "robot_scale@robot"]

ONE_PLACE_EACH = [
    ("joint_offset", "joint3"),
    ("link_length", "joint2"),
    ("joint_compliance", "joint2"),
    ("backlash", "joint4"),
    ("encoder_eccentricity", "joint5"),
    ("thermal_drift", "robot"),
    ("base_frame", "base"),
    ("tool_offset", "tool"),
    ("time_latency", "camera"),
    ("depth_scale", "camera"),
    ("depth_bias", "camera"),
    ("robot_scale", "robot"),
]


def _scenario(name: str) -> str:
    # the two uniform scales are exactly confounded once the frame is fitted (tested in
    # test_gap_robot_scale.py): each is named at its place with known frames
    return "known" if name in KNOWN_FRAME_EFFECTS or name in BOTH_SCENARIOS else "tracker"


def _check_closed(res) -> None:
    b, a = res.before, res.after
    assert a.cv_rms <= 1.2 * b.noise_rms, (a.cv_rms * 1e3, b.noise_rms * 1e3)
    assert b.cv_rms > 1.3 * a.cv_rms  # the gap shrank visibly
    for fe, _ in res.effects:
        for p, sd in fe.param_std.items():
            assert np.isfinite(fe.params[p]) and np.isfinite(sd) and sd > 0, (p, fe.params[p], sd)


@pytest.mark.parametrize(("name", "where"), ONE_PLACE_EACH, ids=[f"{n}@{w}" for n, w in ONE_PLACE_EACH])
def test_each_catalog_effect_is_named_at_its_place(name, where):
    _, res = run(case([(name, where)], scenario=_scenario(name)))
    assert res.named == [(name, where)], res.reason
    assert res.verdict == "explained", res.reason
    _check_closed(res)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "where"),
    [("joint_compliance", "joint3"), ("backlash", "joint2"), ("time_latency", "camera"), ("depth_bias", "camera")],
)
def test_low_magnitude_effects_are_named_too(name, where):
    _, res = run(case([(name, where)], "low", scenario=_scenario(name), seed=11))
    assert res.named == [(name, where)], res.reason
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms


@pytest.mark.parametrize(
    "effects",
    [
        [("joint_compliance", "joint2"), ("backlash", "joint3")],
        [("encoder_eccentricity", "joint4"), ("time_latency", "camera")],
    ],
    ids=["compliance+backlash", "eccentricity+latency"],
)
def test_two_effects_together_are_both_named(effects):
    _, res = run(case(effects, seed=3))
    assert sorted(res.named) == sorted(effects), res.reason
    assert res.verdict == "explained"
    _check_closed(res)


@pytest.mark.parametrize(("scenario", "seed"), [("tracker", 21), ("tracker", 22), ("known", 23)])
def test_pure_noise_gives_no_gap(scenario, seed):
    _, res = run(case([], scenario=scenario, seed=seed))
    assert res.verdict == "no_gap", res.reason
    assert res.named == []
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms


def test_fitted_values_match_the_hidden_ones():
    """Compliance of joint 2 and backlash of joint 3, both hidden: the fitted values within 4 sigma."""
    camp, res = run(case([("joint_compliance", "joint2"), ("backlash", "joint3")], seed=3))
    truth = {type(e).__name__: e for e in camp.truth.effects}
    fitted = {fe.name: fe for fe, _ in res.effects}
    c_true = truth["JointCompliance"].compliance_rad_per_nm[0]
    c = fitted["joint_compliance"]
    assert abs(c.params["compliance_joint2"] - c_true) < 4 * c.param_std["compliance_joint2"] + 1e-3 * abs(c_true)
    b_true = truth["Backlash"].width_rad[0]
    b = fitted["backlash"]
    assert abs(b.params["backlash_joint3"] - b_true) < 4 * b.param_std["backlash_joint3"] + 1e-3 * abs(b_true)
    assert b.param_std["backlash_joint3"] < 0.1 * b_true  # and well determined (physical units: rad)


@pytest.mark.parametrize("seed", [41, 42])
def test_an_effect_outside_the_catalog_is_unexplained_not_misnamed(seed):
    """A lateral sensor distortion quadratic in the image coordinates (no catalog effect has it)."""
    c = case([], seed=seed)
    camp = make_case(c)
    p = camp.data.samples.positions
    u, v = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    d = np.column_stack([(u**2 - np.mean(u**2)) * p[:, 2], (u * v - np.mean(u * v)) * p[:, 2], np.zeros(len(p))])
    d *= 2.5e-4 / np.sqrt(np.mean(np.sum(d**2, axis=1)))  # 0.25 mm RMS: about 3x the noise floor
    camp.data.samples.positions = p + d
    camp.data.range_m = np.linalg.norm(camp.data.samples.positions, axis=1)
    res = analyse_gap(camp.model, camp.data, noise_mm=0.05, calibrate=c.calibrate, families=families(),
                      config=GapConfig(SelectionConfig(cv_folds=4)))  # fmt: skip
    assert res.verdict == "unexplained" and res.named == [], res.reason
    assert not res.after.consistent and res.after.cv_rms > 2 * res.before.noise_rms


@pytest.mark.parametrize("effects", [[("backlash", "joint3")], []], ids=["backlash@joint3", "noise-only"])
def test_the_other_shipped_robot_abb_irb120(effects):
    from plugins.sim.model_gap.simulate import LEVELS, HiddenEffect, simulate_campaign

    hidden = tuple(HiddenEffect(n, w, LEVELS["high"]) for n, w in effects)
    camp = simulate_campaign(hidden, n_samples=160, seed=2, robot="abb_irb120")
    res = analyse_gap(camp.model, camp.data, noise_mm=0.05, calibrate=("frame", "tool"), families=families(),
                      config=GapConfig(SelectionConfig(cv_folds=4)))  # fmt: skip
    assert res.named == [tuple(e) for e in effects], res.reason
    assert res.verdict == ("explained" if effects else "no_gap")
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms


def _benchmark_run(effects, level: str, seed: int, scenario: str = "tracker"):
    """One case exactly as benchmarks/gap.py runs it (200 samples, 5 folds)."""
    from plugins.model_gap import KinematicGapProblem, ProblemConfig
    from plugins.model_gap.core import run_gap
    from plugins.sim.model_gap.simulate import LEVELS, HiddenCase, HiddenEffect

    hidden = tuple(HiddenEffect(n, w, LEVELS[level]) for n, w in effects)
    c = HiddenCase("x", "pair", level, scenario, hidden, seed)
    camp = make_case(c)
    problem = KinematicGapProblem(camp.model, camp.data, ProblemConfig(c.calibrate, noise_m=c.noise_m))
    return run_gap(problem, families(), GapConfig())


def test_an_ambiguous_pair_does_not_block_a_decisive_effect():
    """Low link_length@joint4 + depth_scale (a benchmark case that used to end `unexplained` at 1.25x the
    floor): depth_scale ranks first but is not decisive (over link_length@joint2/3 while link_length@joint4's
    signal is in the residuals, and over its exact twin robot_scale); link_length@joint4 is decisive and is
    named first. Then depth_scale is tied with robot_scale (the frame is fitted): not named, added as one
    tie term, and the gap closes."""
    res = _benchmark_run([("link_length", "joint4"), ("depth_scale", "camera")], "low", 1766459159)
    first = res.iterations[0].decision
    assert first.status == "named" and first.winner.label == "link_length@joint4"
    assert "ranked higher but not decisive:" in first.reason and "depth_scale@camera" in first.reason
    assert res.named == [("link_length", "joint4")], res.reason
    assert res.confounded == SCALES, res.reason
    assert [t.label for t in res.tie_terms] == ["|".join(SCALES)]
    assert res.verdict == "explained_up_to_tie" and res.reason.startswith("link_length@joint4 added; ")
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms


def test_a_tie_term_lets_the_backward_check_remove_a_link_length_stand_in():
    """High link_length@joint2 + robot_scale, frame fitted (a benchmark case that ended with a wrong name at
    1.05x the floor): the two together look like joint 3's length (one of the two long lengths a uniform
    scale stretches), so round 1 leads with link_length@joint3 (tied with joint 3's fast thermal growth, it
    joins as a tie term that resolves as the length once link_length@joint2 is named in round 2); round 3
    ties the two scales. While the tie added nothing, link_length@joint3 stayed in for part of the scale;
    with the tie term in the model its BIC gain given the others is negative and the backward check removes
    it: the exact hidden effect is named, the scale is the tie term, the gap closes."""
    res = _benchmark_run([("link_length", "joint2"), ("robot_scale", "robot")], "high", 1827525663)
    assert res.iterations[0].decision.winner.label == "link_length@joint3"  # the stand-in, first
    tie_round = next(it for it in res.iterations if "robot_scale@robot" in it.decision.tied)
    assert sorted(tie_round.decision.tied) == SCALES and tie_round.added.tied
    assert [lab for lab, gain in tie_round.removed if gain < 0] == ["link_length@joint3"]
    assert res.named == [("link_length", "joint2")], res.reason
    assert [t.label for t in res.tie_terms] == ["|".join(SCALES)]
    assert res.verdict == "explained_up_to_tie", res.reason
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms, res.after.cv_rms / res.before.noise_rms


def test_the_backward_check_removes_a_stand_in_named_first():
    """High tool_offset + depth_bias with known frames: round 1 names depth_scale (it mimics parts of
    both); once tool_offset and depth_bias are in, depth_scale's BIC gain given them is negative and it
    is removed again -- it used to stay in the final model, a wrong name."""
    res = _benchmark_run([("tool_offset", "tool"), ("depth_bias", "camera")], "high", 1394635031, "known")
    assert res.iterations[0].added.name == "depth_scale"
    removed = [lab for it in res.iterations for lab, gain in it.removed if gain < 0]
    assert removed == ["depth_scale@camera"]
    assert sorted(res.named) == [("depth_bias", "camera"), ("tool_offset", "tool")], res.reason
    assert res.verdict == "explained"
    from plugins.model_gap.core.report import report_dict

    rep = report_dict(res)
    assert [e["effect"] for e in rep["effects_removed"]] == ["depth_scale@camera"]
    assert sorted(e["name"] for e in rep["effects_added"]) == ["depth_bias", "tool_offset"]


def test_an_approximate_tie_resolves_once_a_later_effect_is_in():
    """Low thermal_drift@robot + depth_bias (the benchmark's one identifiable case vgr used to miss): with
    the range bias still in the residuals the drift ties with link_length@joint4 and joint 4's own growth
    (round 1: a tie term, evaluated as the drift); once depth_bias is named the drift is decisive over
    the other two given it, so the tie is resolved and the drift named: the exact hidden pair, verdict ``explained``."""
    from plugins.model_gap.core.report import report_dict

    res = _benchmark_run([("thermal_drift", "robot"), ("depth_bias", "camera")], "low", 1943253138)
    first = res.iterations[0]
    assert first.decision.status == "ambiguous" and first.added.tied
    tie = ["link_length@joint4", "thermal_drift@joint4", "thermal_drift@robot"]  # and joint 4's link growth
    assert sorted(first.decision.tied) == tie
    assert res.resolved_ties == {"|".join(tie): "thermal_drift@robot"}
    assert sorted(res.named) == [("depth_bias", "camera"), ("thermal_drift", "robot")], res.reason
    assert res.tie_terms == [] and res.confounded == [] and res.verdict == "explained"
    assert res.after.cv_rms <= 1.2 * res.before.noise_rms
    rep = report_dict(res)
    drift = next(e for e in rep["effects_added"] if e["name"] == "thermal_drift")
    assert not drift["tied"] and drift["resolved_tie"] == "|".join(tie)
    (group,) = rep["confounded"]
    assert group["added"] and group["resolved_as"] == "thermal_drift@robot"
