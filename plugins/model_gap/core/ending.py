"""The end of the loop: the share rule applied to the model, and what to measure next.

After the last round (:func:`plugins.model_gap.core.workflow.run_gap`) the end test of the final
round's structure (:mod:`.end_test`) says whether structure is left. If it is, every non-geometric
term is scored by :func:`.share.shares`; those below ``min_share`` are removed from the problem (which
refits the rest) and the final round is examined again on the model without them, so the report,
the verdict and the files describe the model that is kept. :func:`advice_for` gives the campaign to
measure when the verdict is ``unexplained``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from plugins.model_gap.core.end_test import campaign_advice
from plugins.model_gap.core.interfaces import FittedEffect, GapProblem
from plugins.model_gap.core.iteration import Iteration
from plugins.model_gap.core.selection import CandidateScore, Decision
from plugins.model_gap.core.share import ShareCheck, shares


def end_inputs(problem: GapProblem) -> dict[str, Any]:
    """What the end test takes from a problem that offers it (error directions, replicate groups, whether
    the noise was stated): keyword arguments of :func:`.structure.residual_structure` but ``noise_trust``."""
    dirs = getattr(problem, "error_directions", None)
    reps = getattr(problem, "replicate_groups", None)
    return {
        "directions": dirs() if callable(dirs) else None,
        "replicates": reps() if callable(reps) else None,
    }


def stated(problem: GapProblem) -> bool:
    """The noise was given (an option or a data column), not estimated from the residuals."""
    return str(getattr(problem, "noise_source", "given")) != "estimated"


def apply_share_rule(
    problem: GapProblem,
    iterations: list[Iteration],
    effects: list[tuple[FittedEffect, CandidateScore]],
    min_share: float,
    margin: float,
    is_geometric: Callable[[Any], bool],
    examine: Callable[[int], Iteration],
) -> ShareCheck | None:
    """The share rule of :mod:`.share` on the final model; ``effects`` and ``iterations`` are updated in
    place (terms dropped, a closing round examined by ``examine(index)``). None: no structure left."""
    last = iterations[-1]
    st = last.structure
    if st is None or not st.found or not effects:
        return None
    lin = problem.linearise()
    current = {f.representative: f for f in problem.fitted_effects()}
    terms, labels = [], {}
    for fe, sc in effects:
        if is_geometric(sc.candidate):
            continue
        cand = sc.candidate
        n_lin = len(cand.param_names) - len(cand.shape_names)
        now = current.get(fe.representative, fe)
        joint, regressor = getattr(cand, "joint", None), getattr(cand, "regressor", None)
        own = f"joint{joint}~{regressor}" if joint and regressor else None  # the term's own structure design
        terms.append((fe.representative, n_lin, now.vector(cand.param_names[:n_lin]), own))
        labels[fe.representative] = fe.label
    ins = end_inputs(problem)
    check = shares(lin, st, terms, problem.features(), ins["directions"], min_share, margin)
    check.shares = {labels[k]: v for k, v in check.shares.items()}
    check.gain_given_structure = {labels[k]: v for k, v in check.gain_given_structure.items()}
    low = [e for e in effects if e[0].label in check.shares and not check.kept(e[0].label)]
    if not low:
        return check
    for fe, sc in low:
        problem.remove_effect(sc.candidate)
        check.dropped.append((fe.label, check.shares[fe.label]))
    effects[:] = [e for e in effects if not any(e is x for x in low)]
    closing = examine(last.index + 1)
    dropped = ", ".join(check.why(lab) for lab, _ in check.dropped)
    closing.decision = Decision("none", None, f"the share rule took out {dropped}")
    iterations.append(closing)
    return check


def advice_for(iterations: list[Iteration]) -> list[str]:
    """What to measure when the final residuals keep structure ([] when none is left)."""
    st = iterations[-1].structure
    if st is None or not st.found:
        return []
    return campaign_advice(st.significant, st.pure_error_variance is not None)
