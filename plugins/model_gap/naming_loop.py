"""The naming loop and verdict rules the camera and depth gap workflows share (their module
docstrings): rounds of score / decide / add over the catalog until nothing is eligible or the effect
limit is reached (:func:`name_effects`), an added term's label (:class:`LabelledTerm`), and the verdict
rules both apply (:func:`limit_or_structure`, :func:`named_verdict`). What is cross-validated, and in
which unit, stays in each workflow."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["LabelledTerm", "NamingRun", "limit_or_structure", "name_effects", "named_verdict"]


class LabelledTerm:
    """Mixin of an added term (``effect``, ``tied_with``): its label, the names joined by ``|``."""

    @property
    def label(self) -> str:
        term: Any = self
        return "|".join(e.name for e in (term.effect, *term.tied_with))


@dataclass
class NamingRun:
    """What :func:`name_effects` found: the rounds, the terms added, their effects, the baseline's and
    the final model's cross-validation, and whether the effect limit stopped it with a candidate eligible."""

    rounds: list[Any]
    added: list[Any]
    effects: list[Any]
    baseline: Any
    final: Any
    still_eligible: bool


def name_effects(
    catalog: Sequence[Any],
    baseline: Any,
    max_effects: int,
    evaluate: Callable[[Any, list[Any], list[Any]], tuple[list[Any], Any, dict[str, Any]]],
    rms: Callable[[Any], float],
    round_type: Callable[..., Any],
    term_type: Callable[..., Any],
) -> NamingRun:
    """The rounds: ``evaluate(current, effects, candidates)`` gives the candidates' scores, the
    decision (camera.selection.Decision) and each candidate's cross-validation by name; each round is
    ``round_type(iteration, rms(current), scores, decision)``, each term added
    ``term_type(effect, tied_with, parsimony_over, iteration, rms before, rms after, p_corrected)``."""
    current = baseline
    effects: list[Any] = []
    added: list[Any] = []
    rounds: list[Any] = []
    excluded: set[str] = set()
    still_eligible = False
    for iteration in range(1, len(catalog) + 1):
        candidates = [e for e in catalog if e.name not in excluded]
        if not candidates:
            break
        scores, decision, cvs = evaluate(current, effects, candidates)
        rounds.append(round_type(iteration, rms(current), scores, decision))
        chosen = decision.added
        if chosen is None:
            break
        if len(added) >= max_effects:
            still_eligible = True
            break
        after = cvs[chosen.name]
        score = next(s for s in scores if s.effect is chosen)
        tied = tuple(e for e in decision.tie if e is not chosen)
        added.append(
            term_type(chosen, tied, decision.parsimony_over, iteration, rms(current), rms(after), score.p_corrected)
        )
        effects.append(chosen)
        excluded |= {chosen.name, *(e.name for e in decision.tie)}
        current = after
    return NamingRun(rounds, added, effects, baseline, current, still_eligible)


def limit_or_structure(names: str, after: Any, still_eligible: bool, cfg: Any, over: str) -> tuple[str, str] | None:
    """``unexplained`` when the effect limit stopped the loop with a candidate eligible, or when the
    structure test *after* (``p_value``, ``describe()``, ``advice()``) finds structure left at
    ``cfg.alpha``; else None. *names* the terms added, *over* what is measured (views, captures)."""
    if still_eligible:
        return "unexplained", f"--max-effects {cfg.max_effects} reached with a candidate still predicting better"
    if after.p_value < cfg.alpha:
        return "unexplained", (
            f"added {names}; structure is left in the residuals (p = {after.p_value:.2g} < {cfg.alpha:g}): "
            f"{after.describe()}; an effect outside the catalog or too few {over} to name it: {after.advice()}"
        )
    return None


def named_verdict(kept: Sequence[Any], names: str, over: str) -> tuple[str, str]:
    """With nothing left to explain: ``no_gap`` (no term), ``explained_up_to_tie`` (a tie term among
    *kept*) or ``explained``."""
    if not kept:
        return "no_gap", f"no catalog effect predicts held-out {over} better than the noise explains; no structure left"
    if any(a.tied_with for a in kept):
        return "explained_up_to_tie", f"added {names}; no structure left, but a tie term is in the model"
    return "explained", f"named {names}; no structure left in the residuals"
