"""Shared helpers of the model-gap tests: hidden-effect datasets and one call to the workflow."""

from __future__ import annotations

from functools import cache

from plugins.model_gap import analyse_gap, builtin_families
from plugins.model_gap.core import GapConfig, GapResult, SelectionConfig
from plugins.sim.model_gap.simulate import LEVELS, HiddenCase, HiddenEffect, SimulatedCampaign, make_case

N_SAMPLES = 160  # smaller than the benchmark's 200: the tests must stay quick on 2 cores
FOLDS = 4


def case(effects: list[tuple[str, str]], level: str = "high", *, scenario: str = "tracker", seed: int = 7):
    hidden = tuple(HiddenEffect(n, w, LEVELS[level]) for n, w in effects)
    kind = "noise" if not hidden else ("single" if len(hidden) == 1 else "pair")
    label = "+".join(f"{n}@{w}" for n, w in effects) or "noise"
    return HiddenCase(label, kind, level if hidden else "none", scenario, hidden, seed, n_samples=N_SAMPLES)


@cache
def families():
    return builtin_families()


def run(c: HiddenCase, report_dir=None) -> tuple[SimulatedCampaign, GapResult]:
    camp = make_case(c)
    cfg = GapConfig(SelectionConfig(cv_folds=FOLDS, seed=0))
    res = analyse_gap(
        camp.model,
        camp.data,
        noise_mm=c.noise_m * 1e3,
        calibrate=c.calibrate,
        config=cfg,
        families=families(),
        report_dir=report_dir,
    )
    return camp, res
