"""The model-gap report: ``gap_report.json`` and the terminal (rich) view of a :class:`GapResult`.

JSON (``format: vgr.gap_report/1``), lengths in the problem's report unit (mm for robot data):

* ``verdict`` (``explained`` | ``explained_up_to_tie`` | ``unexplained`` | ``no_gap``) and ``reason``;
* ``effects_added``: ``[{name, where, tied, params, param_std, units, cv_rms_gain_mm, delta_bic,
  p_value_corrected, independent_fraction, iteration, config}]`` (params SI, with their units):
  ``params`` / ``param_std`` / ``config`` are those of the *final* joint refit of every effect with
  the baseline (the augmented model file has the same); the scores are from the round that added it.
  ``convention``: present when the best fit has the other sign of the effect's convention (a backlash
  against the data's ``dir`` columns): the value is given in the physical convention, and the note
  says that the data count the other way round.
  A *tie term* (``tied: true``) is named after its whole group, never after one member:
  ``name`` ``a|b``, ``where`` ``x|y``, ``label`` ``a@x|b@y``, ``members``; ``representative`` is the
  member the model evaluates (its ``params`` / ``config``; the model file stores it with
  ``tied_with``), ``note`` and ``advice`` say what it means and what would separate the members;
* ``rms_before_mm`` / ``rms_after_mm``: held-out (k-fold cross-validated) 3-D RMS of the model as given
  (after its baseline calibration) and of the final augmented model; ``noise_floor_mm``: the 3-D RMS
  the stated noise alone gives; ``noise_source``: ``given`` | ``data column sigma_mm`` | ``estimated``;
* ``noise_check``: the final residuals against that noise (``ratio`` = ``sqrt(chi2 / dof)`` with
  ``dof`` = residuals - fitted parameters, both tails' p-values, ``agrees``) and, when they disagree,
  which to ``believe`` and why (``note``; :mod:`.verdict`);
* ``residual_structure``: ``before`` / ``after``, the noise-independent F-tests of what systematic
  residual the model leaves (per feature, a smooth field over the workspace; :mod:`.structure`),
  which decide whether a gap is left;
* ``before`` / ``after``: in-sample RMS, max, per axis, chi-square test (``ratio_to_noise`` =
  ``sqrt(chi2 / chi2_dof)``);
* ``confounded``: every round that ended with tied candidates (they explain the same part of the
  gap, e.g. a range scale and a uniform robot scale once the frame is fitted), ``[{effects,
  delta_bic, tied_with, advice, iteration, added, term, representative}]``: none of them is named;
  ``added`` says whether the group joined the model as the tie term ``term`` (else the loop stopped
  there: ``max_effects``); ``tied_with`` maps each to the others, ``advice`` says what data would
  separate them; empty when no round was tied;
  A tie term of an earlier round that later effects resolved (one member decisive over the others
  given them) is replaced by that member, named, with ``resolved_tie`` (the tie's label); its
  ``confounded`` entry says ``resolved_as``;
* ``effects_removed``: effects named in an earlier round and dropped by the backward check once the
  later ones explained them (``delta_bic_given_others < 0``);
* ``iterations``: per round the comparison, where the gap concentrates, every candidate's scores and
  the decision; ``absorbed`` and ``not_testable`` candidates with the reason; ``decision_rule``;
  ``problem`` (model, data, baseline calibration); ``files`` (plots, model files);
* ``outliers`` (the samples left out as gross errors) and ``end_test`` (structure left after the last
  named effect, where it concentrates, the share rule, the campaign to measure): :mod:`.report_end`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from engine.plain_data import plain
from plugins.model_gap.core.interfaces import FittedEffect
from plugins.model_gap.core.iteration import Comparison, Iteration
from plugins.model_gap.core.localise import FeatureGap
from plugins.model_gap.core.report_end import end_dict, outliers_dict, print_end
from plugins.model_gap.core.selection import CandidateScore
from plugins.model_gap.core.structure import StructureTest
from plugins.model_gap.core.workflow import GapResult

REPORT_FORMAT = "vgr.gap_report/1"

_DISPLAY = {  # SI unit -> (factor, display unit)
    "rad": (1e6, "urad"),
    "m": (1e3, "mm"),
    "rad/(N m)": (1e6, "urad/(N m)"),
    "1": (1e6, "ppm"),
}


def display(value: float, unit: str) -> tuple[float, str]:
    """A parameter in the unit people read (urad, mm, ms, ppm)."""
    if unit == "s":
        return (value * 1e3, "ms") if abs(value) < 1.0 else (value, "s")
    f, u = _DISPLAY.get(unit, (1.0, unit))
    return value * f, u


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _fields(obj: Any, *names: str) -> dict[str, Any]:
    """``{name: obj.name}`` for each of *names*: what the report carries as the result has it."""
    return {n: getattr(obj, n) for n in names}


def _comparison(c: Comparison, s: float) -> dict[str, Any]:
    return {
        "rms": c.rms * s,
        "max": c.max * s,
        "rms_axis": [v * s for v in c.rms_axis],
        "mean_axis": [v * s for v in c.mean_axis],
        "held_out_rms": c.cv_rms * s,
        "noise_rms": c.noise_rms * s,
        "ratio_to_noise": c.ratio_to_noise,
        "chi2": c.chi2,
        "chi2_dof": c.dof,  # residuals - fitted parameters
        "chi2_p": c.chi2_p,
        "consistent_with_noise": c.consistent,
    }


def _score(sc: CandidateScore, s: float) -> dict[str, Any]:
    return {
        **_fields(sc, "name", "where", "k", "k_shape", "independent_fraction"),
        "confounded_with": [{"param": n, "coef": c} for n, c in sc.confounded_with],
        **_fields(sc, "absorbed", "unavailable", "delta_rss"),
        "delta_bic": _finite(sc.delta_bic),
        "f_stat": _finite(sc.f_stat),
        "p_value": sc.p_value,
        "p_value_corrected": sc.p_adjusted,
        "cv_rms": _finite(sc.cv_rms * s),
        "cv_gain": sc.cv_gain * s,
        **_fields(sc, "cv_z", "shape", "eligible", "reasons"),
    }


def _feature(g: FeatureGap, s: float) -> dict[str, Any]:
    return {
        "feature": g.name,
        **_fields(g, "label", "unit", "mean_chi2", "mean_p", "spread_chi2", "spread_p", "log10_p", "z"),
        "bins": [{"range": b.label, "n": b.n, "rms": b.rms * s, "mean": [v * s for v in b.mean]} for b in g.bins],
    }


def report_dict(result: GapResult) -> dict[str, Any]:
    """The JSON-ready report (see the module docstring)."""
    s, u = result.report_scale, result.report_unit
    first = result.iterations[0]
    return {
        "format": REPORT_FORMAT,
        "verdict": result.verdict,
        "reason": result.reason,
        "effects_added": _effects_added(result),
        "confounded": _confounded(result),
        "effects_removed": [
            {"effect": lab, "iteration": it.index, "delta_bic_given_others": g}
            for it in result.iterations
            for lab, g in it.removed
        ],
        f"rms_before_{u}": result.before.cv_rms * s,
        f"rms_after_{u}": result.after.cv_rms * s,
        f"noise_floor_{u}": result.before.noise_rms * s,
        "noise_source": result.problem.get("noise_source", "given"),
        "noise_check": _noise_check(result, s),
        "residual_structure": {
            "before": _structure(result.iterations[0].structure),
            "after": _structure(result.iterations[-1].structure),
        },
        "unit": u,
        "before": _comparison(result.before, s),
        "after": _comparison(result.after, s),
        "absorbed": [
            {"name": c.name, "where": c.where, "acts_like": [n for n, _ in c.confounded_with]}
            for c in first.scores
            if c.absorbed
        ],
        "not_testable": [
            {"name": c.name, "where": c.where, "reason": c.unavailable} for c in first.scores if c.unavailable
        ],
        "decision_rule": _decision_rule(result),
        "problem": result.problem,
        "iterations": [_iteration(it, s) for it in result.iterations],
        "files": result.files,
        "outliers": outliers_dict(result),
        "end_test": end_dict(result),
    }


def _effects_added(result: GapResult) -> list[dict[str, Any]]:
    """``effects_added``: every effect of the final model with the values and sigmas of the final joint
    refit and the scores of the round that added it (a resolved tie's member: the tie's round)."""
    s, u = result.report_scale, result.report_unit
    round_of = {id(it.added_score): it.index for it in result.iterations if it.added_score is not None}
    tie_round = {it.added.label: it.index for it in result.iterations if it.added is not None and it.added.tied}
    resolved_round = {named: tie_round.get(tie) for tie, named in result.resolved_ties.items()}
    effects = []
    for fe, sc in result.effects:  # values and sigmas of the final joint refit
        e: dict[str, Any] = {"name": fe.tie_name, "where": fe.tie_where, "tied": fe.tied}
        if fe.tied:
            e |= _fields(fe, "label", "members", "representative")
        e |= {
            **_fields(fe, "params", "param_std", "units"),
            f"cv_rms_gain_{u}": sc.cv_gain * s,
            "delta_bic": sc.delta_bic,
            "p_value_corrected": sc.p_adjusted,
            "independent_fraction": sc.independent_fraction,
            "iteration": round_of.get(id(sc), resolved_round.get(fe.label)),
            "config": fe.config,
        }
        if fe.note:  # e.g. the data count a direction the other way round: the value is the physical one
            e["convention"] = fe.note
        if fe.label in resolved_round:  # named once a later round resolved the tie it was part of
            e["resolved_tie"] = next(t for t, n in result.resolved_ties.items() if n == fe.label)
        if fe.tied:
            it = result.iterations[round_of[id(sc)]] if id(sc) in round_of else None
            e["note"] = tie_note(fe)
            e["advice"] = (list(it.decision.advice) if it is not None else []) or ["collect data that separates them"]
        effects.append(e)
    return effects


def _decision_rule(result: GapResult) -> dict[str, Any]:
    """``decision_rule``: the test levels and options the result was decided with."""
    sel = result.config.selection
    return {
        "alpha_familywise": sel.alpha,
        **_fields(sel, "bic_margin", "cv_folds", "cv_z", "absorbed_tol"),
        "chi2_alpha": result.config.chi2_alpha,
        "max_effects": result.config.max_effects,
        "seed": sel.seed,
    }


def _iteration(it: Iteration, s: float) -> dict[str, Any]:
    """One entry of ``iterations``: the round's comparison, localisation, ranked candidates, decision and
    what it changed in the model."""
    return {
        "index": it.index,
        "comparison": _comparison(it.comparison, s),
        "localisation": [_feature(g, s) for g in it.localisation],
        "candidates": [_score(c, s) for c in sorted(it.scores, key=_rank)],
        "decision": {
            "status": it.decision.status,
            "reason": it.decision.reason,
            "winner": it.decision.winner.label if it.decision.winner else None,
            "contenders": [{"label": lab, "delta_bic_given": g} for lab, g in it.decision.contenders],
            "tied": it.decision.tied,
            "advice": it.decision.advice,
            "representative": it.decision.representative.label if it.decision.representative else None,
        },
        "added": None if it.added is None else it.added.label,
        "added_tied": bool(it.added is not None and it.added.tied),
        "resolved": [{"tie": t, "named": n, "reason": why} for t, n, why in it.resolved],
        "removed": [lab for lab, _ in it.removed],
        "model_file": it.model_file,
    }


def _noise_check(result: GapResult, s: float) -> dict[str, Any] | None:
    n = result.noise
    if n is None:
        return None
    return {
        "source": n.source,
        f"stated_sigma_{result.report_unit}": n.stated_sigma * s,
        f"residual_sigma_{result.report_unit}": n.residual_sigma * s,
        **_fields(n, "ratio", "chi2", "dof", "p_above", "p_below", "agrees", "believe", "note"),
    }


def _structure(st: StructureTest | None) -> dict[str, Any] | None:
    if st is None:
        return None
    return {
        "found": st.found,
        "alpha_familywise": st.alpha,
        "n_tests": st.n_tests,
        "tests": [
            _fields(f, "design", "label", "k", "dof", "f_stat", "p_value", "p_corrected") for f in st.findings[:8]
        ],
    }


def tie_note(fe: FittedEffect) -> str:
    """What a tie term means, for the report and the terminal."""
    return (
        f"tie term, not a named effect: the data cannot tell {' and '.join(fe.members)} apart (they predict the "
        f"same data within the decision margin); the model evaluates it as {fe.representative}, which does not "
        "say that this one is the cause"
    )


def _confounded(result: GapResult) -> list[dict[str, Any]]:
    out = []
    resolved = result.resolved_ties
    for it, group in result.tie_groups:
        d = it.decision
        added = it.added is not None and it.added.tied
        term = it.added.label if added and it.added is not None else None
        out.append(
            {
                "effects": group,
                "delta_bic": dict(d.tied_delta_bic),
                "tied_with": {lab: [o for o in group if o != lab] for lab in group},
                "advice": list(d.advice) or ["collect data that separates them"],
                "iteration": it.index,
                "added": added,
                "term": term,
                "representative": it.added.representative if added and it.added is not None else None,
                "resolved_as": resolved.get(term) if term else None,
            }
        )
    return out


def _rank(c: CandidateScore) -> tuple:
    return (not c.testable, -(c.delta_bic if np.isfinite(c.delta_bic) else -1e300))


def write_json(result: GapResult, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(plain(report_dict(result), nan_as_none=True), indent=2), encoding="utf-8")
    return path


# --------------------------------------------------------------------------- terminal


def _fmt_params(params: dict[str, float], std: dict[str, float], units: dict[str, str]) -> str:
    parts = []
    for k, v in params.items():
        val, unit = display(v, units.get(k, ""))
        sd, _ = display(std.get(k, float("nan")), units.get(k, ""))
        parts.append(f"{k} = {val:.4g} ± {sd:.2g} {unit}")
    return "; ".join(parts)


def render(result: GapResult, console: Console, *, top: int = 8) -> None:
    """Print the report: verdict, before/after table, localisation, candidates, effects, files."""
    _print_gap(result, console)
    _print_noise_and_baseline(result, console)
    _print_localisation(result, console)
    for it in result.iterations:
        _print_round(it, result, console, top)
    _print_ties(result, console)
    _print_effects(result, console)
    print_end(result, console)
    first = result.iterations[0]
    absorbed = [c.label for c in first.scores if c.absorbed]
    if absorbed:
        console.print(f"absorbed by the calibration (cannot be told apart from it): {', '.join(absorbed)}")
    missing = sorted({f"{c.name} ({c.unavailable})" for c in first.scores if c.unavailable})
    if missing:
        console.print("not testable on these data: " + "; ".join(missing), soft_wrap=True)
    for name, path in result.files.items():
        console.print(f"{name}: {escape(path)}", highlight=False, soft_wrap=True)


def _print_gap(result: GapResult, console: Console) -> None:
    """The verdict and the table of the gap before / after (held-out and in-sample RMS, the noise test)."""
    s, u = result.report_scale, result.report_unit
    colour = {"explained": "green", "no_gap": "green", "explained_up_to_tie": "cyan", "unexplained": "yellow"}[
        result.verdict
    ]
    console.print(f"[bold {colour}]{result.verdict}[/]: {escape(result.reason)}", soft_wrap=True)
    b, a = result.before, result.after
    t = Table(title=f"gap before / after ({u})", title_justify="left")
    for col in ("", "model as given + calibration", "augmented model", "noise floor"):
        t.add_column(col, justify="right" if col else "left")
    t.add_row("held-out RMS (k-fold)", f"{b.cv_rms * s:.4f}", f"{a.cv_rms * s:.4f}", f"{b.noise_rms * s:.4f}")
    t.add_row("in-sample RMS", f"{b.rms * s:.4f}", f"{a.rms * s:.4f}", f"{b.noise_rms * s:.4f}")
    t.add_row("max", f"{b.max * s:.4f}", f"{a.max * s:.4f}", "")
    for i, ax in enumerate(("x", "y", "z")[: len(b.rms_axis)]):
        t.add_row(f"RMS {ax}", f"{b.rms_axis[i] * s:.4f}", f"{a.rms_axis[i] * s:.4f}", "")
    t.add_row("x the noise: sqrt(chi2 / dof), dof = residuals - parameters", f"{b.ratio_to_noise:.3f}",
              f"{a.ratio_to_noise:.3f}", "1")  # fmt: skip
    t.add_row("consistent with the noise", str(b.consistent), str(a.consistent), "")
    sb, sa = result.iterations[0].structure, result.iterations[-1].structure
    if sb is not None and sa is not None:
        t.add_row("systematic residual left (F-tests)", str(sb.found), str(sa.found), "")
    console.print(t)


def _print_noise_and_baseline(result: GapResult, console: Console) -> None:
    """The noise check, the baseline calibration and its notes, a warning when the noise was estimated."""
    if result.noise is not None:
        colour = "green" if result.noise.agrees else "yellow"
        console.print(f"[{colour}]noise check:[/] {escape(result.noise.note)}", soft_wrap=True)
    cal = result.problem.get("calibration") or {}
    if cal:
        levels = ", ".join(cal.get("levels") or []) or "none (the model's frames are trusted)"
        n = len(cal.get("parameters") or [])
        console.print(f"baseline calibration: {escape(levels)} ({n} parameters)", soft_wrap=True)
        for note in cal.get("notes") or []:
            console.print(f"  {escape(note)}", soft_wrap=True)
    if result.problem.get("noise_source") == "estimated":
        console.print(
            "[yellow]noise not given: estimated from the data (residual of every candidate fitted at once); "
            "a gap outside the catalog would be counted as noise. Give --noise-mm for a real test.[/]"
        )


def _print_localisation(result: GapResult, console: Console) -> None:
    """Where the first model's gap concentrates: the 5 strongest features, RMS per bin."""
    s, u = result.report_scale, result.report_unit
    first = result.iterations[0]
    if first.localisation:
        t = Table(title="where the gap concentrates (first model)", title_justify="left")
        for col in ("feature", "z", f"RMS per bin ({u})"):
            t.add_column(col)
        for g in first.localisation[:5]:
            bins = ", ".join(f"{bn.label}: {bn.rms * s:.3f}" for bn in g.bins)
            t.add_row(f"{g.label} ({g.unit})" if g.unit else g.label, f"{g.z:.1f}", bins)
        console.print(t)


def _print_round(it: Iteration, result: GapResult, console: Console, top: int) -> None:
    """One round: its ``top`` testable candidates with their scores and verdicts, the decision's reason,
    the effects removed again and the ties resolved."""
    s, u = result.report_scale, result.report_unit
    t = Table(title=f"round {it.index + 1}: candidates ({it.decision.status})", title_justify="left")
    for col in ("effect", "k", "indep.", "dBIC", "p corr.", f"CV gain {u}", "verdict"):
        t.add_column(col, justify="left" if col in ("effect", "verdict") else "right")
    ranked = [c for c in sorted(it.scores, key=_rank) if c.testable][:top]
    tied = set(it.decision.tied) if it.decision.status == "ambiguous" else set()
    for c in ranked:
        t.add_row(
            c.label,
            str(c.k + c.k_shape),
            f"{c.independent_fraction:.2f}",
            f"{c.delta_bic:.1f}",
            f"{c.p_adjusted:.2g}",
            f"{c.cv_gain * s:+.4f}",
            _candidate_mark(it, c, tied),
        )
    console.print(t)
    console.print(f"  {escape(it.decision.reason)}", soft_wrap=True)
    for lab, g in it.removed:
        console.print(f"  removed again: {escape(lab)} (the later effects explain it: dBIC given them {g:.1f})")
    for tie, lab, why in it.resolved:
        console.print(f"  tie resolved: {escape(tie)} -> {escape(lab)} named ({escape(why)})", soft_wrap=True)


def _candidate_mark(it: Iteration, c: CandidateScore, tied: set[str]) -> str:
    """A candidate's verdict column: named, tied (in the tie term or not), eligible, or why not."""
    if it.added is not None and it.added_score is c and not it.added.tied:
        mark = "[green]named[/]"
    elif c.label in tied:
        mark = "[cyan]tied[/] (in the tie term)" if it.added is not None else "[yellow]tied[/]"
    else:
        mark = "eligible" if c.eligible else ""
    if not c.eligible and c.reasons and c.label not in tied:
        mark = escape(c.reasons[0])
    return mark


def _print_ties(result: GapResult, console: Console) -> None:
    """Every round that ended tied: resolved later (the member named), or none named and what would
    separate them."""
    resolved = result.resolved_ties
    for it, group in result.tie_groups:
        added = it.added is not None and it.added.tied
        what = (
            f"added as one tie term {it.added.label} (evaluated as {it.added.representative})"
            if added and it.added is not None
            else "not added (at most max-effects terms)"
        )
        if added and it.added is not None and it.added.label in resolved:
            console.print(
                f"[bold green]tie resolved:[/] {escape(' = '.join(group))} were tied in round {it.index + 1}; "
                f"{escape(resolved[it.added.label])} is named, decisive once the later effects were in",
                soft_wrap=True,
            )
            continue
        console.print(
            f"[bold yellow]tied, none named:[/] {escape(' = '.join(group))} explain the same part of the gap; "
            f"{escape(what)}",
            soft_wrap=True,
        )
        for a in it.decision.advice or ["collect data that separates them"]:
            console.print(f"  to separate them: {escape(a)}", soft_wrap=True)


def _print_effects(result: GapResult, console: Console) -> None:
    """The effects of the final model with their parameters ± 1 sigma and held-out gain, and their notes."""
    s, u = result.report_scale, result.report_unit
    if result.effects:
        t = Table(title="effects added (SI values shown in urad, mm, ms, ppm)", title_justify="left")
        for col in ("effect", "parameters ± 1 sigma", f"held-out gain {u}"):
            t.add_column(col)
        for fe, sc in result.effects:
            label = f"{fe.label}\n(tie, not named; evaluated as {fe.representative})" if fe.tied else fe.label
            params = _fmt_params(fe.params, fe.param_std, fe.units)
            t.add_row(escape(label), params, f"{sc.cv_gain * s:.4f}")
        console.print(t)
        for fe, _ in result.effects:
            if fe.note:
                console.print(f"  {escape(fe.label)}: {escape(fe.note)}", soft_wrap=True)
