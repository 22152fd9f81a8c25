"""The model-gap loop: compare, name, add, repeat; then the verdict.

1. **Compare**: residuals of the current model (RMS, max, per component, chi-square against the
   noise specification) and where they concentrate (:mod:`engine.gap.localise`).
2. **Name**: score every candidate effect from the plugins' catalog (:mod:`engine.gap.selection`)
   and apply the decision rule.
3. **Add**: the problem adds the named effect and refits everything (nonlinear least squares); the
   augmented model is written as a new model file when a report directory is given. The effects of
   the result carry the values and uncertainties of the *final* joint refit (an effect added early
   moves when later ones join); each round keeps the values it added.
4. Backward check: an earlier effect that the later ones now explain (BIC gain given all the others
   below 0) is removed again (:func:`_prune`).
5. Repeat while a candidate is named (at most ``max_effects``): the loop stops when no decisive
   candidate is left. The chi-square test does not stop the loop; it decides the verdict.

Verdict: ``no_gap`` when nothing was added, no candidate is significant and the residuals are
consistent with the noise (chi-square test at ``chi2_alpha``); ``explained`` when effects were added
and the final residuals are consistent with the noise; ``unexplained`` otherwise (a significant gap
no candidate names decisively, an ambiguous choice -- tied candidates, none of them named, see
:attr:`GapResult.confounded` -- or residuals still above the noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from .interfaces import Candidate, EffectFamily, FittedEffect, GapInputError, GapProblem, Linearisation, Signature
from .localise import FeatureGap, localise
from .selection import BaselineScore, CandidateScore, Decision, SelectionConfig, decide, gain_given_others, score_all


@dataclass
class GapConfig:
    """Options of :func:`run_gap`."""

    selection: SelectionConfig = field(default_factory=SelectionConfig)
    max_effects: int = 4
    chi2_alpha: float = 1e-3  # residuals consistent with the noise unless p < chi2_alpha
    min_residual_dof: int = 20  # residual degrees of freedom left after the largest candidate


@dataclass
class Comparison:
    """The gap of one model: physical residual statistics and the chi-square test (SI units)."""

    rms: float  # 3-D RMS over samples
    max: float  # largest per-sample norm
    rms_axis: list[float]
    mean_axis: list[float]
    chi2: float
    dof: int
    chi2_p: float
    consistent: bool
    cv_rms: float  # held-out (k-fold) RMS
    noise_rms: float  # 3-D RMS the noise alone would give

    @property
    def ratio_to_noise(self) -> float:
        return self.rms / self.noise_rms if self.noise_rms > 0 else np.inf


@dataclass
class Iteration:
    index: int
    comparison: Comparison
    localisation: list[FeatureGap]
    scores: list[CandidateScore]
    decision: Decision
    residual: np.ndarray  # (N, m) physical residuals of this iteration's model
    whitened: np.ndarray
    added: FittedEffect | None = None  # as fitted in this round (the result's effects: final values)
    added_score: CandidateScore | None = None
    signature: Signature | None = None
    # (N, m) physical contribution of the added effect (linearised, this round's fit): in full, and the
    # part the model before it (baseline calibration + earlier effects) cannot absorb -- what the
    # residuals can show, since the calibration takes the rest
    contribution: np.ndarray | None = None
    identifiable: np.ndarray | None = None
    model_file: str | None = None
    # earlier effects dropped after this round's addition: (label, BIC gain given the others < 0)
    removed: list[tuple[str, float]] = field(default_factory=list)


@dataclass
class GapResult:
    verdict: str
    reason: str
    iterations: list[Iteration]
    effects: list[tuple[FittedEffect, CandidateScore]]
    problem: dict[str, Any]
    config: GapConfig
    report_unit: str
    report_scale: float
    files: dict[str, str] = field(default_factory=dict)

    @property
    def before(self) -> Comparison:
        return self.iterations[0].comparison

    @property
    def after(self) -> Comparison:
        return self.iterations[-1].comparison

    @property
    def named(self) -> list[tuple[str, str]]:
        return [(fe.name, fe.where) for fe, _ in self.effects]

    @property
    def confounded(self) -> list[str]:
        """The candidates tied in the last round (they explain the same part of the gap; none was named)."""
        d = self.iterations[-1].decision
        return list(d.tied) if d.status == "ambiguous" else []


def compare(lin: Linearisation, baseline: BaselineScore, chi2_alpha: float) -> Comparison:
    phys = lin.physical_residual()
    norms = np.linalg.norm(phys, axis=1)
    chi2 = baseline.rss
    dof = max(1, baseline.dof)
    p = float(stats.chi2.sf(chi2, dof))
    return Comparison(
        rms=float(np.sqrt(np.mean(norms**2))),
        max=float(norms.max()),
        rms_axis=np.sqrt(np.mean(phys**2, axis=0)).tolist(),
        mean_axis=phys.mean(axis=0).tolist(),
        chi2=float(chi2),
        dof=int(dof),
        chi2_p=p,
        consistent=p >= chi2_alpha,
        cv_rms=baseline.cv_rms,
        noise_rms=float(np.sqrt(np.mean(lin.sigma**2) * lin.n_components)),
    )


def collect_candidates(problem: GapProblem, families: list[EffectFamily]) -> list[Candidate]:
    """Every candidate of every family (one per place the effect can act)."""
    out: list[Candidate] = []
    for fam in families:
        out.extend(fam.candidates(problem))
    return out


def _check_size(lin: Linearisation, candidates: list[Candidate], cfg: GapConfig) -> None:
    k_max = max((len(c.param_names) for c in candidates if not c.unavailable), default=0)
    M, p = lin.residual.size, lin.jacobian.shape[2]
    folds = cfg.selection.cv_folds
    need = int(np.ceil((p + k_max + cfg.min_residual_dof) / lin.n_components * folds / (folds - 1)))
    need = max(need, 2 * folds)
    if lin.n_samples < need:
        raise GapInputError(
            f"{lin.n_samples} samples are too few: the calibration fits {p} parameters and the largest candidate "
            f"{k_max} more, and {folds}-fold cross-validation must leave >= {cfg.min_residual_dof} residual "
            f"degrees of freedom: give at least {need} samples"
        )
    if p >= M:
        raise GapInputError(f"{M} residuals for {p} calibration parameters: add samples")


def run_gap(
    problem: GapProblem,
    families: list[EffectFamily],
    config: GapConfig | None = None,
    *,
    model_dir: str | Path | None = None,
) -> GapResult:
    """Run the loop of the module docstring; write each augmented model to ``model_dir`` if given."""
    cfg = config or GapConfig()
    if cfg.selection.cv_folds < 2:
        raise GapInputError("cross-validation needs at least 2 folds")
    candidates = collect_candidates(problem, families)
    if not candidates:
        raise GapInputError("no candidate effects: is a plugin providing vgr_model_effects loaded?")
    out_dir = Path(model_dir) if model_dir is not None else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    iterations: list[Iteration] = []
    effects: list[tuple[FittedEffect, CandidateScore]] = []
    added_labels: set[tuple[str, str]] = set()
    files: dict[str, str] = {}
    for index in range(cfg.max_effects + 1):
        lin = problem.linearise()
        if index == 0:
            _check_size(lin, candidates, cfg)
        active = [c for c in candidates if (c.name, c.where) not in added_labels]
        scorer, baseline, scores = score_all(lin, active, problem, cfg.selection)
        decision = decide(scorer, scores, cfg.selection)
        it = Iteration(
            index,
            compare(lin, baseline, cfg.chi2_alpha),
            localise(lin, problem.features()),
            scores,
            decision,
            lin.physical_residual(),
            lin.residual.copy(),
        )
        if index == 0 and out_dir is not None:
            files["model_baseline"] = str(problem.save_model(out_dir / "model_0_baseline.yaml"))
        iterations.append(it)
        if decision.status != "named" or index == cfg.max_effects:
            break
        w = decision.winner
        assert w is not None and w.design is not None
        it.signature = w.candidate.signature(problem)
        it.contribution = (w.design.columns @ w.beta) * lin.sigma[:, None]
        it.identifiable = scorer.identifiable_part(w.design, w.beta) * lin.sigma[:, None]
        it.added = problem.add_effect(w.candidate, w.values)
        it.added_score = w
        effects.append((it.added, w))
        added_labels.add((w.name, w.where))  # never tested again, even if pruned below (no cycles)
        it.removed = _prune(problem, effects)
        if out_dir is not None:
            it.model_file = str(problem.save_model(out_dir / f"model_{index + 1}_{w.name}_{w.where}.yaml"))
    # the effects as the final joint refit has them (values and sigmas move when later effects are added)
    final = {(fe.name, fe.where): fe for fe in problem.fitted_effects()}
    effects = [(final.get((fe.name, fe.where), fe), sc) for fe, sc in effects]
    verdict, reason = _verdict(iterations, effects, cfg)
    scale = float(getattr(problem, "report_scale", 1.0))
    unit = str(getattr(problem, "report_unit", ""))
    return GapResult(verdict, reason, iterations, effects, problem.describe(), cfg, unit, scale, files)


def _prune(problem: GapProblem, effects: list[tuple[FittedEffect, CandidateScore]]) -> list[tuple[str, float]]:
    """Backward check after an addition: drop an earlier effect the others now explain.

    Forward selection compares single effects; with two effects hidden, the first one named can be
    a stand-in that mimics parts of both (a range scale for a range bias plus a tool offset). After
    each addition every *earlier* effect is scored given all the others (:func:`gain_given_others`);
    while the worst has a BIC gain below 0 (the evidence favours the model without it) it is removed
    and the model refitted. Entering needs a gain of ``bic_margin``, staying only ``> 0``: the band
    between is hysteresis, and a removed effect is not tested again, so the loop cannot cycle.
    """
    removed: list[tuple[str, float]] = []
    while len(effects) > 1:
        lin = problem.linearise()
        final = {(fe.name, fe.where): fe for fe in problem.fitted_effects()}
        worst: tuple[float, int] | None = None
        for i, (fe, sc) in enumerate(effects[:-1]):
            cand = sc.candidate
            n_lin = len(cand.param_names) - len(cand.shape_names)
            now = final[(fe.name, fe.where)]
            values = np.array([now.params[p] for p in cand.param_names[:n_lin]])
            gain = gain_given_others(lin, f"{fe.name}@{fe.where}", n_lin, values)
            if worst is None or gain < worst[0]:
                worst = (gain, i)
        if worst is None or worst[0] >= 0.0:
            break
        fe, sc = effects.pop(worst[1])
        problem.remove_effect(sc.candidate)
        removed.append((f"{fe.name}@{fe.where}", worst[0]))
    return removed


def _verdict(iterations: list[Iteration], effects: list, cfg: GapConfig) -> tuple[str, str]:
    last = iterations[-1]
    c = last.comparison
    noise = f"residual RMS {c.ratio_to_noise:.2f}x the noise ({'consistent' if c.consistent else 'inconsistent'}, "
    noise += f"chi2 = {c.chi2:.0f} for {c.dof} dof, p = {c.chi2_p:.2g})"
    if last.decision.status == "named":  # stopped by max_effects with a candidate still decisive
        return "unexplained", f"more than {cfg.max_effects} effects would be needed; next: {last.decision.reason}"
    if last.decision.status == "ambiguous":  # tied candidates: none is named
        done = ", ".join(f"{e.name}@{e.where}" for e, _ in effects)
        return "unexplained", (f"{done} added; then " if done else "") + f"{last.decision.reason}; {noise}"
    if not c.consistent:
        if effects:
            done = ", ".join(f"{e.name}@{e.where}" for e, _ in effects)
            return "unexplained", f"{done} added, but no catalog effect explains the rest decisively: {noise}"
        return "unexplained", f"no catalog effect explains the gap decisively: {noise}"
    if effects:
        return "explained", f"{', '.join(f'{e.name}@{e.where}' for e, _ in effects)} added; {noise}"
    return "no_gap", f"no candidate effect is significant; {noise}"
