"""The benchmark's a-priori classes (identifiable / confounded / undetectable) come from the truth alone.

:mod:`plugins.sim.model_gap.detectability` classifies a hidden-effect case from the simulated
truth (noise-free displacements, true frames) before any method sees the data: a strong single
effect is identifiable, two effects built to cancel are undetectable, an effect with the same
signature as another catalog effect is confounded -- whatever the noise draw, and the measured data
play no part. Also the identity behind the ``robot_scale`` effect of docs/model_gap.md: after a frame
calibration a range scale is a uniform scale of all robot lengths and the tool point (the catalog's
``robot_scale``), and each is the other's rival.
"""

from __future__ import annotations

import numpy as np
import pytest
from model_gap_helpers import N_SAMPLES

from plugins.model_gap.core.selection import _basis, _perp
from plugins.model_gap.effects import RobotScaleFamily
from plugins.model_gap.problem import KinematicGapProblem, ProblemConfig
from plugins.sim.model_gap.detectability import classify, uniform_scale_column
from plugins.sim.model_gap.simulate import LEVELS, TOOL_TRUE, HiddenCase, HiddenEffect, make_case

pytestmark = pytest.mark.timeout(300)

# a joint-6 zero offset rotates the tool point about the flange axis: the same displacement as a tool
# offset along z x t (flange frame); with this direction and the offset's + sign the two cancel
TANGENTIAL = tuple(np.cross([0.0, 0.0, 1.0], TOOL_TRUE).tolist())


def _case(effects, scenario: str, seed: int = 7, level: str = "high") -> HiddenCase:
    hidden = tuple(HiddenEffect(*e[:2], LEVELS[level], *e[2:]) for e in effects)
    kind = "single" if len(hidden) == 1 else "pair"
    return HiddenCase("t", kind, level, scenario, hidden, seed, n_samples=N_SAMPLES)


def _classify(c: HiddenCase):
    return classify(c, make_case(c))


@pytest.mark.parametrize("seed", [7, 11])
def test_a_strong_single_effect_is_identifiable(seed):
    cc = _classify(_case([("joint_compliance", "joint2")], "tracker", seed))
    assert cc.cls == "identifiable"
    (e,) = cc.effects
    # the hidden gap is 0.15 mm (3-D RMS) over N samples at 0.05 mm per axis: lambda = N (0.15 / 0.05)^2
    assert cc.lambda_gap == pytest.approx(N_SAMPLES * 9.0, rel=1e-3)
    assert cc.power_det > 0.999 and e.power > 0.999 and e.lambda_id > 100
    assert e.identifiable and cc.identifiable_part == [e.label]


def test_a_pair_built_to_cancel_is_undetectable():
    c = _case([("joint_offset", "joint6", (1.0,)), ("tool_offset", "tool", tuple(-x for x in TANGENTIAL))], "known")
    camp = make_case(c)
    cc = classify(c, camp)
    # each alone leaves 0.15 mm; together they cancel (to second order in the offsets)
    assert camp.gap_m < 1e-2 * LEVELS["high"]
    assert cc.cls == "undetectable" and cc.power_det < 0.01 and cc.identifiable_part == []
    assert all(e.lambda_alone > 100 for e in cc.effects)  # it is the sum that vanishes, not each effect


def test_the_same_pair_adding_up_is_detectable_but_confounded():
    c = _case([("joint_offset", "joint6", (1.0,)), ("tool_offset", "tool", TANGENTIAL)], "known")
    cc = _classify(c)
    assert cc.cls == "confounded" and cc.power_det > 0.999
    # either effect explains the other's signal: nothing of either is independent
    assert all(e.lambda_id < 1e-6 * e.lambda_alone and not e.identifiable for e in cc.effects)


def test_a_tangential_tool_offset_is_confounded_with_a_joint6_offset():
    cc = _classify(_case([("tool_offset", "tool", TANGENTIAL)], "known"))
    assert cc.cls == "confounded"
    (e,) = cc.effects
    assert e.rival == "joint_offset@joint6" and e.lambda_id < 1e-6 * e.lambda_alone


def test_the_class_uses_the_truth_not_the_measurements():
    c = _case([("depth_bias", "camera")], "tracker", level="low")
    camp = make_case(c)
    before = classify(c, camp).to_dict()
    rng = np.random.default_rng(0)
    camp.data.samples.positions[:] += rng.normal(0.0, 1e-3, camp.data.samples.positions.shape)  # 20x the noise
    assert classify(c, camp).to_dict() == before
    assert before["cls"] == "identifiable"


def test_noise_only_is_its_own_class():
    c = HiddenCase("n", "noise", "none", "tracker", (), 3, n_samples=N_SAMPLES)
    cc = _classify(c)
    assert cc.cls == "noise" and cc.lambda_gap == 0.0 and cc.effects == []


def test_a_range_scale_is_a_uniform_scale_of_the_robot_after_frame_calibration():
    # tracker scenario: frame + tool calibrated; the range scale's displacement lies in the span of the
    # calibration and ONE column, the uniform scale of every DH length and the tool point
    camp = make_case(_case([("depth_scale", "camera")], "tracker"))
    s = camp.signal_m.reshape(-1)
    C, u = camp.calibration_m, uniform_scale_column(camp)
    assert np.linalg.norm(_perp(_basis(C), s)) > 0.3 * np.linalg.norm(s)  # the calibration alone leaves a gap
    assert np.linalg.norm(_perp(_basis(np.column_stack([C, u])), s)) < 1e-9 * np.linalg.norm(s)
    # the catalog's robot_scale candidate is that column (computed here independently of the catalog)
    problem = KinematicGapProblem(camp.truth_model, camp.truth_data, ProblemConfig((), noise_m=1.0))
    (rs,) = RobotScaleFamily().candidates(problem)
    (d,) = rs.designs(problem)
    np.testing.assert_allclose(d.columns.reshape(-1), u, rtol=0, atol=1e-9 * np.abs(u).max())
    # known frames: the same up to a constant shift, the range scale of the base's position e t
    known = make_case(_case([("depth_scale", "camera")], "known"))
    e = known.camera.depth_scale - 1.0
    shift = known.signal_m - e * uniform_scale_column(known).reshape(-1, 3)
    t_base = known.truth_model.T_world_base[:3, 3]
    np.testing.assert_allclose(shift, np.broadcast_to(e * t_base, shift.shape), atol=1e-12)


@pytest.mark.parametrize(("hidden", "rival"), [("depth_scale@camera", "robot_scale@robot"),
                                               ("robot_scale@robot", "depth_scale@camera")])  # fmt: skip
def test_with_a_fitted_frame_the_two_scales_are_each_others_rival(hidden, rival):
    """robot_scale is in the catalog, so the classification finds it as a rival by itself: with the frame
    fitted either scale is confounded (nothing independent of the other), with known frames identifiable."""
    name, where = hidden.split("@")
    cc = _classify(_case([(name, where)], "tracker"))
    (e,) = cc.effects
    assert cc.cls == "confounded" and e.rival == rival and e.lambda_id < 1e-9 * e.lambda_alone
    assert cc.identifiable_part == []
    cc = _classify(_case([(name, where)], "known"))
    assert cc.cls == "identifiable" and cc.effects[0].power > 0.99 and cc.effects[0].rival != rival
