"""Randomised guidance trials (tests/guidance_trials.py): the draws are what the issue asks for,
and random draws of each scenario converge and dock within the issue's bounds (truth).

The full Monte Carlo (100 runs per scenario) is benchmarks/guidance.py; here a few draws per scenario
keep the suite's time in check while still exercising offsets, hand-eye errors and noise that no
shipped recipe has.
"""

from __future__ import annotations

import guidance_trials as gt
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.transforms import angle_between
from plugins.params import PoseSpec

pytestmark = pytest.mark.timeout(600)


@settings(max_examples=25, deadline=None)
@given(st.sampled_from(sorted(gt.SCENARIOS)), st.integers(0, 2**31 - 1))
def test_draws_follow_the_issue_and_repeat_for_a_seed(scenario: str, seed: int) -> None:
    data, offsets, errors = gt.draw(scenario, seed)
    again, _, _ = gt.draw(scenario, seed)
    assert data == again
    spec = gt.TrialSpec()
    for o in offsets.values():
        assert np.all(np.abs(np.asarray(o.translation_m[:2])) <= spec.offset_mm / 1e3) and o.translation_m[2] == 0
        assert abs(np.degrees(o.rotation_rotvec_rad[2])) <= spec.offset_deg and o.rotation_rotvec_rad[:2] == (0, 0)
    _, believers, _ = gt.SCENARIOS[scenario]
    for guidance, camera in believers.items():
        true = gt.mount_pose(data, camera)
        believed = PoseSpec.model_validate(data["stages"][guidance]["params"]["hand_eye"]).T()
        assert np.linalg.norm(believed[:3, 3] - true[:3, 3]) * 1e3 == pytest.approx(spec.hand_eye_mm, rel=1e-9)
        assert np.degrees(angle_between(believed[:3, :3], true[:3, :3])) == pytest.approx(spec.hand_eye_deg, rel=1e-6)
        assert errors[guidance].shape == (6,)


# (max docking error mm, deg) from the issue; dual: 0.2 mm (no angle given; 0.1 deg checked)
BOUNDS = {"eye_in_hand": (0.1, 0.05), "eye_to_hand": (0.1, 0.05), "dual": (0.2, 0.1)}


@pytest.mark.parametrize(("scenario", "seed"), [("eye_in_hand", 7), ("eye_to_hand", 8), ("dual", 9)])
def test_a_random_draw_converges_and_docks_within_bounds(scenario: str, seed: int) -> None:
    trial = gt.run_trial(scenario, seed)
    assert trial.ok, trial.stop_reason
    assert trial.converged and all(m <= 5 for m in trial.moves.values()), trial.guidance
    assert trial.alarms == []
    max_mm, max_deg = BOUNDS[scenario]
    ev = trial.evaluation
    assert ev["docked"] and ev["error_mm"] < max_mm and ev["error_deg"] < max_deg, ev
    # every usable look's T_match travels with the result
    for g in trial.guidance.values():
        assert len(g.matches) == len(g.residual_mm) == g.moves + 1


def test_hand_eye_error_is_what_slows_the_loop_not_what_biases_it() -> None:
    """Same draw with the hand-eye error 0 vs 1 mm / 0.5 deg: the wrong hand-eye costs moves (the
    first correction misses and the loop iterates: measured 1 vs 2), not accuracy (both dock within
    0.02 mm of each other, far under the 0.1 mm bound)."""
    exact = gt.run_trial("eye_in_hand", 21, gt.TrialSpec(hand_eye_mm=0.0, hand_eye_deg=0.0))
    wrong = gt.run_trial("eye_in_hand", 21)
    assert exact.offsets == wrong.offsets
    for t in (exact, wrong):
        assert t.converged and t.evaluation["error_mm"] < 0.1
    assert sum(wrong.moves.values()) > sum(exact.moves.values())
    assert abs(wrong.evaluation["error_mm"] - exact.evaluation["error_mm"]) < 0.02
