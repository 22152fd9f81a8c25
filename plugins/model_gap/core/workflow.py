"""The model-gap loop: compare, name, add, repeat; then the verdict.

1. **Compare**: residuals of the current model (RMS, max, per component, chi-square against the
   noise specification) and where they concentrate (:mod:`plugins.model_gap.core.localise`).
2. **Name**: score every candidate effect from the plugins' catalog (:mod:`plugins.model_gap.core.selection`)
   and apply the decision rule.
3. **Add**: the problem adds the named effect and refits everything (nonlinear least squares); the
   augmented model is written as a new model file when a report directory is given. The effects of
   the result carry the values and uncertainties of the *final* joint refit (an effect added early
   moves when later ones join); each round keeps the values it added.
4. Backward check: an earlier effect that the later ones now explain (BIC gain given all the others
   below 0) is removed again (:func:`_prune`).
5. **Ties.** A round whose eligible candidates are all tied (they explain the same part of the gap
   within the decision margin, e.g. a range scale and a uniform robot scale once the frame is
   fitted) names none of them, but adds the group as *one tie term*: the model is evaluated with
   the group's representative (:func:`plugins.model_gap.core.selection.representative`), and the term is
   reported under the whole group's name (``a@x|b@y``, :class:`FittedEffect` with ``tied_with``),
   never as the representative alone. Its members are not tested again as new candidates. So the
   model closes the gap (prediction and held-out RMS reach the noise) while nothing is named that
   the data cannot show. After each later addition every tie term is re-examined given the rest of
   the model (:func:`_resolve_ties`): an approximate tie can separate once another effect's signal
   has left the residuals, and a member decisive over the others (the naming rule's margin) is then
   named in place of the term. An exact tie never resolves.
6. Repeat while a candidate is named or a tie term added (at most ``max_effects`` terms; a geometric
   term -- a joint zero, a link length, the frames: :func:`is_geometric` -- does not count, a real
   robot has them all): the loop stops when no eligible candidate is left. The chi-square test does
   not stop the loop.

7. **The honest end** (:mod:`.end_test`, :mod:`.share`, :mod:`.ending`): the final residuals are
   tested for structure against references the residuals did not produce (each joint's error as a
   smooth function of every feature, replicate measurements, the stated noise within
   ``noise_trust``); when structure is left, a term that explains less than ``min_share`` of what
   the model without it leaves is taken out again, and the result says what to measure next.

The verdict (:mod:`.verdict`) does not depend on the stated noise (within ``noise_trust``): whether a
gap is left is decided by noise-independent F-tests of the final residuals (:mod:`.structure`), and the chi-square test
against the stated noise is reported as the *noise check* (which of the two to believe when they
disagree). ``no_gap``: nothing added and no structure left; ``explained``: effects added, every one
named, no structure left; ``explained_up_to_tie``: the same with a tie term among them;
``unexplained``: structure left that no candidate names decisively, or ``max_effects`` reached.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from plugins.model_gap.core.end_test import DEFAULT_NOISE_TRUST
from plugins.model_gap.core.ending import advice_for, apply_share_rule, end_inputs, stated
from plugins.model_gap.core.interfaces import (
    Candidate,
    EffectFamily,
    FittedEffect,
    GapInputError,
    GapProblem,
    Linearisation,
    tie_label,
)
from plugins.model_gap.core.iteration import Comparison, Iteration
from plugins.model_gap.core.localise import localise
from plugins.model_gap.core.robust import DEFAULT_OUTLIER_ALPHA, OutlierScreen
from plugins.model_gap.core.selection import (
    BaselineScore,
    CandidateScore,
    Decision,
    Scorer,
    SelectionConfig,
    _basis,
    _perp,
    decide,
    gain_given_others,
    score_all,
)
from plugins.model_gap.core.share import DEFAULT_MIN_SHARE, ShareCheck
from plugins.model_gap.core.structure import residual_structure
from plugins.model_gap.core.verdict import NoiseCheck, decide_verdict, noise_check

#: the verdicts, from the best news to the worst (see the module docstring)
VERDICTS = ("no_gap", "explained", "explained_up_to_tie", "unexplained")


@dataclass
class GapConfig:
    """Options of :func:`run_gap`."""

    selection: SelectionConfig = field(default_factory=SelectionConfig)
    max_effects: int = 4
    chi2_alpha: float = 1e-3  # residuals consistent with the noise unless p < chi2_alpha
    min_residual_dof: int = 20  # residual degrees of freedom left after the largest candidate
    noise_trust: float = DEFAULT_NOISE_TRUST  # a stated noise is believed to this factor (end test)
    min_share: float = DEFAULT_MIN_SHARE  # structure left: a term must explain this share of what is left
    outlier_alpha: float = DEFAULT_OUTLIER_ALPHA  # P(a Gaussian campaign loses any good sample); 0: no screen


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
    noise: NoiseCheck | None = None  # the final residuals against the stated (or estimated) noise
    share: ShareCheck | None = None  # structure left at the end: each term's share of it (None: none left)
    advice: list[str] = field(default_factory=list)  # unexplained: what to measure next
    outliers: OutlierScreen | None = None  # the samples left out as gross errors (set by the caller's screen)

    @property
    def before(self) -> Comparison:
        return self.iterations[0].comparison

    @property
    def after(self) -> Comparison:
        return self.iterations[-1].comparison

    @property
    def named(self) -> list[tuple[str, str]]:
        """The effects named and added (a tie term is added, never named)."""
        return [(fe.name, fe.where) for fe, _ in self.effects if not fe.tied]

    @property
    def tie_terms(self) -> list[FittedEffect]:
        """The tie terms of the final model (each stands for a group the data cannot tell apart)."""
        return [fe for fe, _ in self.effects if fe.tied]

    @property
    def tie_groups(self) -> list[tuple[Iteration, list[str]]]:
        """Every round that ended tied, with its group (added as a tie term unless the loop stopped there)."""
        return [(it, sorted(it.decision.tied)) for it in self.iterations if it.decision.status == "ambiguous"]

    @property
    def unresolved_tie(self) -> list[str]:
        """A tie the loop stopped on without adding it (``max_effects`` reached), else []."""
        last = self.iterations[-1]
        return sorted(last.decision.tied) if last.decision.status == "ambiguous" and last.added is None else []

    @property
    def resolved_ties(self) -> dict[str, str]:
        """Tie terms resolved in a later round: tie label -> the member named instead."""
        return {tie: named for it in self.iterations for tie, named, _ in it.resolved}

    @property
    def confounded(self) -> list[str]:
        """Every candidate of a tie that stayed a tie (added as a tie term, or left when the loop stopped),
        sorted; none of them is named. Ties a later round resolved are in :attr:`resolved_ties`."""
        done = self.resolved_ties
        return sorted({lab for _, group in self.tie_groups if tie_label(group) not in done for lab in group})


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


def is_geometric(candidate: Candidate) -> bool:
    """A candidate that is part of the model's geometry (a joint zero, a link length, the frames): its
    ``geometric`` attribute. Geometric terms never use up ``max_effects`` (a real robot has them all)."""
    return bool(getattr(candidate, "geometric", False))


def samples_needed(n_params: int, candidates: list[Candidate], n_components: int, cfg: GapConfig) -> int:
    """Samples the workflow needs for a model fitting ``n_params`` parameters and these candidates:
    ``cv_folds``-fold cross-validation must leave ``min_residual_dof`` residual degrees of freedom after
    the model and the largest candidate."""
    k_max = max((len(c.param_names) for c in candidates if not c.unavailable), default=0)
    folds = cfg.selection.cv_folds
    need = int(np.ceil((n_params + k_max + cfg.min_residual_dof) / n_components * folds / (folds - 1)))
    return max(need, 2 * folds)


def _check_size(lin: Linearisation, candidates: list[Candidate], cfg: GapConfig) -> None:
    k_max = max((len(c.param_names) for c in candidates if not c.unavailable), default=0)
    M, p = lin.residual.size, lin.jacobian.shape[2]
    folds = cfg.selection.cv_folds
    need = samples_needed(p, candidates, lin.n_components, cfg)
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
    candidates = _checked_candidates(problem, families, cfg)
    out_dir = Path(model_dir) if model_dir is not None else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    iterations: list[Iteration] = []
    effects: list[tuple[FittedEffect, CandidateScore]] = []
    added_labels: set[tuple[str, str]] = set()
    tie_members: dict[str, list[CandidateScore]] = {}  # tie term (representative label) -> the group's scores
    files: dict[str, str] = {}
    n_terms = 0  # terms that count against max_effects (geometric ones do not: is_geometric)
    for index in range(len(candidates) + 1):  # each candidate joins at most once: the loop ends
        lin = problem.linearise()
        if index == 0:
            _check_size(lin, candidates, cfg)
        active = [c for c in candidates if (c.name, c.where) not in added_labels]
        it, scorer = _examine(problem, lin, active, index, cfg)
        if index == 0 and out_dir is not None:
            files["model_baseline"] = str(problem.save_model(out_dir / "model_0_baseline.yaml"))
        iterations.append(it)
        if it.decision.status == "none":
            break
        by_label = {s.label: s for s in it.scores}
        w, tied_with = _term_to_add(it.decision)
        counts = not all(is_geometric(by_label[lab].candidate) for lab in (w.label, *tied_with))
        if counts and n_terms >= cfg.max_effects:
            break
        n_terms += counts
        added = _add_term(problem, it, lin, scorer, w, tied_with)
        effects.append((added, w))
        # never tested again, even if pruned below (no cycles); a tie's members neither, one by one
        added_labels.add((w.name, w.where))
        added_labels.update((by_label[lab].name, by_label[lab].where) for lab in tied_with)
        it.removed = _prune(problem, effects)
        it.resolved = _resolve_ties(problem, effects, tie_members, cfg.selection.bic_margin)
        if tied_with:
            tie_members[w.label] = [by_label[lab] for lab in sorted({w.label, *tied_with})]
        if out_dir is not None:
            it.model_file = str(problem.save_model(out_dir / f"model_{index + 1}_{added.file_stem}.yaml"))

    def examine(index: int) -> Iteration:
        return _examine(problem, problem.linearise(), [], index, cfg)[0]

    margin = cfg.selection.bic_margin
    share = apply_share_rule(problem, iterations, effects, cfg.min_share, margin, is_geometric, examine)
    result = _result(problem, iterations, effects, cfg, files)
    result.share = share
    if share is not None and share.dropped:
        out = ", ".join(share.why(lab) for lab, _ in share.dropped)
        result.reason += f"; taken out again by the share rule (noise reference: the {share.reference}): {out}"
    result.advice = advice_for(iterations) if result.verdict == "unexplained" else []
    if result.advice:
        result.reason += "; to find what is missing: " + "; ".join(result.advice)
    return result


def _checked_candidates(problem: GapProblem, families: list[EffectFamily], cfg: GapConfig) -> list[Candidate]:
    """The catalog's candidates, after the checks that need no data (enough folds, a non-empty catalog)."""
    if cfg.selection.cv_folds < 2:
        raise GapInputError("cross-validation needs at least 2 folds")
    candidates = collect_candidates(problem, families)
    if not candidates:
        raise GapInputError("no candidate effects: is a plugin providing vgr_model_effects loaded?")
    return candidates


def _examine(
    problem: GapProblem, lin: Linearisation, active: list[Candidate], index: int, cfg: GapConfig
) -> tuple[Iteration, Scorer]:
    """Steps 1 and 2 of one round on the current model's linearisation: score the candidates still
    active and decide; the round (its comparison, localisation, scores, decision, residuals and
    residual structure) and the scorer that judged it."""
    scorer, baseline, scores = score_all(lin, active, problem, cfg.selection)
    decision = decide(scorer, scores, cfg.selection)
    feats = problem.features()
    trust = cfg.noise_trust if stated(problem) else None
    it = Iteration(
        index,
        compare(lin, baseline, cfg.chi2_alpha),
        localise(lin, feats),
        scores,
        decision,
        lin.physical_residual(),
        lin.residual.copy(),
        structure=residual_structure(lin, feats, cfg.chi2_alpha, noise_trust=trust, **end_inputs(problem)),
    )
    return it, scorer


def _term_to_add(decision: Decision) -> tuple[CandidateScore, tuple[str, ...]]:
    """The term a round adds: (the named winner, ()), or for a tie (its representative, the labels of the
    other members)."""
    tied_with: tuple[str, ...]
    if decision.status == "named":
        w, tied_with = decision.winner, ()
    else:  # tied: the group joins as one term, evaluated as its representative, named as the group
        w = decision.representative
        assert w is not None
        tied_with = tuple(sorted(lab for lab in decision.tied if lab != w.label))
    assert w is not None and w.design is not None
    return w, tied_with


def _add_term(
    problem: GapProblem,
    it: Iteration,
    lin: Linearisation,
    scorer: Scorer,
    w: CandidateScore,
    tied_with: tuple[str, ...],
) -> FittedEffect:
    """Step 3: add the round's term to the problem (which refits everything), a tie as one term evaluated
    as ``w``; record on the round what it added: the signature, the contribution and its identifiable
    part (physical units, this round's linearisation), the fitted effect and its score."""
    assert w.design is not None  # _term_to_add
    it.signature = w.candidate.signature(problem)
    it.contribution = (w.design.columns @ w.beta) * lin.sigma[:, None]
    it.identifiable = scorer.identifiable_part(w.design, w.beta) * lin.sigma[:, None]
    if tied_with:
        it.added = problem.add_effect(w.candidate, w.values, tied_with=tied_with)
    else:
        it.added = problem.add_effect(w.candidate, w.values)
    it.added_score = w
    return it.added


def _result(
    problem: GapProblem,
    iterations: list[Iteration],
    effects: list[tuple[FittedEffect, CandidateScore]],
    cfg: GapConfig,
    files: dict[str, str],
) -> GapResult:
    """The loop's outcome: the effects as the final joint refit has them (values and sigmas move when
    later effects are added), the noise check of the final residuals and the verdict."""
    final = {(fe.name, fe.where): fe for fe in problem.fitted_effects()}
    effects = [(final.get((fe.name, fe.where), fe), sc) for fe, sc in effects]
    desc = problem.describe()
    noise = noise_check(iterations[-1], cfg.chi2_alpha, str(desc.get("noise_source", "given")))
    verdict, reason = decide_verdict(iterations, effects, cfg.max_effects, noise)
    scale = float(getattr(problem, "report_scale", 1.0))
    unit = str(getattr(problem, "report_unit", ""))
    return GapResult(verdict, reason, iterations, effects, desc, cfg, unit, scale, files, noise)


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
            values = now.vector(cand.param_names[:n_lin])
            gain = gain_given_others(lin, f"{fe.name}@{fe.where}", n_lin, values)
            if worst is None or gain < worst[0]:
                worst = (gain, i)
        if worst is None or worst[0] >= 0.0:
            break
        fe, sc = effects.pop(worst[1])
        problem.remove_effect(sc.candidate)
        removed.append((fe.label, worst[0]))
    return removed


def _resolve_ties(
    problem: GapProblem,
    effects: list[tuple[FittedEffect, CandidateScore]],
    tie_members: dict[str, list[CandidateScore]],
    margin: float,
) -> list[tuple[str, str, str]]:
    """Re-examine the tie terms of earlier rounds once later effects are in the model.

    A tie is judged on the residuals of its round; an *approximate* tie can separate once another
    effect's signal has left the residuals (a thermal drift and a link length tied next to an
    unmodelled range bias, say). With ``O`` the current model without the tie term, every member is
    scored on top of ``O`` as in :func:`plugins.model_gap.core.selection.decide`: a member that is decisive over
    every other member (its dBIC ``margin`` above theirs, or gaining ``>= margin`` on top of each)
    and has ``dBIC > 0`` and physically valid values is named instead of the tie term (the
    representative untied, or replaced by that member at its fitted values). An exact tie never
    resolves (each member gains ``-k ln M`` on top of the other).
    """
    out: list[tuple[str, str, str]] = []
    for i in range(len(effects)):
        fe0, sc0 = effects[i]
        group = tie_members.get(fe0.representative)
        current = {f.representative: f for f in problem.fitted_effects()}
        fe = current.get(fe0.representative)
        if group is None or fe is None or not fe.tied:
            continue
        lin = problem.linearise()
        M = lin.residual.size
        A = lin.jacobian.reshape(M, -1)
        cols = [j for j, n in enumerate(lin.names) if n.startswith(fe.representative + ".")]
        rest = [j for j in range(A.shape[1]) if j not in cols]
        cand = sc0.candidate
        n_lin = len(cand.param_names) - len(cand.shape_names)
        values = fe.vector(cand.param_names[:n_lin])
        y = lin.residual.reshape(-1) + A[:, cols[:n_lin]] @ values  # the residual of O
        Q = _basis(A[:, rest])
        y_perp = _perp(Q, y)
        rss_o = float(y_perp @ y_perp)
        fits = {}
        for m in group:
            best = None
            for d in m.candidate.designs(problem):
                Bp = _perp(Q, d.columns.reshape(M, -1))
                beta, *_ = np.linalg.lstsq(Bp, y_perp, rcond=1e-10)
                rss = float(np.sum((y_perp - Bp @ beta) ** 2))
                if best is None or rss < best[0]:
                    best = (rss, Bp, beta, d.shape)
            if best is None:
                continue
            rss, Bp, beta, shape = best
            k = int(np.linalg.matrix_rank(Bp)) + len(m.candidate.shape_names)
            dbic = M * np.log(rss_o / max(rss, 1e-300)) - k * np.log(M)
            fits[m.label] = (m, rss, Bp, beta, shape, k, dbic)
        for lab, (m, _rss, Bp, beta, shape, k, dbic) in fits.items():
            lo, hi = np.asarray(m.candidate.lower, float), np.asarray(m.candidate.upper, float)
            if dbic <= 0 or beta.size != lo.size or not (np.all(beta >= lo) and np.all(beta <= hi)):
                continue
            decisive = True
            for other, (_, rss_r, Bp_r, _, _, _, dbic_r) in fits.items():
                if other == lab or dbic_r <= dbic - margin:
                    continue
                both = np.concatenate([Bp_r, Bp], axis=1)
                coef, *_ = np.linalg.lstsq(both, y_perp, rcond=1e-10)
                rss_both = max(float(np.sum((y_perp - both @ coef) ** 2)), 1e-300)
                if M * np.log(rss_r / rss_both) - k * np.log(M) < margin:
                    decisive = False
                    break
            if not decisive:
                continue
            why = f"{lab} is decisive over {', '.join(o for o in fits if o != lab)} given the later effects"
            problem.remove_effect(cand)
            new_values = np.concatenate([beta, [shape[n] for n in m.candidate.shape_names]])
            if lab == fe.representative:
                new_values = fe.vector(cand.param_names)
            new = problem.add_effect(m.candidate, new_values)
            effects[i] = (new, m)
            out.append((fe.label, lab, why))
            break
    return out
