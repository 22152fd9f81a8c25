"""The verdict of a model-gap run, and the noise check: the residuals against the stated noise.

**Verdict** (:data:`plugins.model_gap.core.workflow.VERDICTS`), from the loop's end and the noise-independent
structure tests of the final residuals (:mod:`.structure`):

* ``unexplained``: ``max_effects`` stopped the loop with a candidate still decisive or a tie not
  added, or the final residuals still change systematically (along a feature, or as a smooth field
  over the workspace) and no catalog effect names it decisively;
* otherwise ``explained_up_to_tie`` (a tie term among the added effects), ``explained`` (effects
  added, every one named) or ``no_gap`` (nothing added).

None of this uses the stated noise beyond a factor: the naming rule (F-test, BIC with the variance
estimated, cross-validation) and the structure tests compare residual sums of the same data; the end
test's stated-noise check (:mod:`.end_test`) only fires beyond ``noise_trust`` (default 2) times the
stated noise, so a ``--noise-mm`` off by less than that gives the same verdict and exit code.

**Noise check** (:func:`noise_check`): the chi-square of the final whitened residuals with ``dof =
residuals - fitted parameters``; ``sqrt(chi2 / dof)`` is the residuals "x the noise" (the
a-posteriori sigma over the stated one). When the two disagree (either tail below ``chi2_alpha``)
the report says which to believe: residuals *above* the noise that change systematically are a gap
(believe the stated noise: the excess is not noise); residuals above it *without* structure, or
below it, are the measurement noise as it is (believe the residuals: the noise is about
``ratio x stated``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import stats

from plugins.model_gap.core.interfaces import FittedEffect, tie_label

if TYPE_CHECKING:
    from plugins.model_gap.core.iteration import Iteration
    from plugins.model_gap.core.selection import CandidateScore
    from plugins.model_gap.core.structure import StructureTest


@dataclass
class NoiseCheck:
    """The final residuals against the stated (or estimated) noise (see the module docstring)."""

    source: str  # given | estimated | data column sigma_mm
    stated_sigma: float  # per component, SI (the median over samples)
    residual_sigma: float  # a-posteriori: stated_sigma * ratio
    ratio: float  # sqrt(chi2 / dof)
    chi2: float
    dof: int  # residuals - fitted parameters
    p_above: float  # P(chi2(dof) >= chi2)
    p_below: float  # P(chi2(dof) <= chi2)
    agrees: bool
    believe: str  # both | residuals | stated noise
    note: str


def noise_check(last: Iteration, alpha: float, source: str = "given") -> NoiseCheck:
    """The noise check of the final model (``last``: the loop's last round)."""
    c = last.comparison
    stated = c.noise_rms / np.sqrt(last.residual.shape[1])
    return check_noise(c.chi2, c.dof, stated, last.structure, alpha, source)


def check_noise(
    chi2: float, dof: int, stated: float, structure: StructureTest | None, alpha: float, source: str = "given"
) -> NoiseCheck:
    """The noise check of whitened residuals with sum of squares ``chi2`` on ``dof`` degrees of freedom
    against the ``stated`` per-component sigma (SI), given what the structure tests found."""
    dof = max(1, int(dof))
    ratio = float(np.sqrt(chi2 / dof))
    p_above, p_below = float(stats.chi2.sf(chi2, dof)), float(stats.chi2.cdf(chi2, dof))
    what = "estimated noise" if source == "estimated" else "stated noise"
    fig = f"{ratio:.2f}x the {what} (chi2 = {chi2:.0f} for {dof} dof = residuals - fitted parameters)"
    sig, res_sig = (f"{x * 1e3:.3g} mm" if x < 1.0 else f"{x:.3g}" for x in (stated, stated * ratio))
    if p_above >= alpha and p_below >= alpha:
        believe, note = "both", f"the residuals agree with the {what}: {fig}"
    elif p_above < alpha and structure is not None and structure.found:
        believe = "stated noise"
        note = (
            f"the residuals are {fig} and change systematically, {structure.describe()}: the excess is a gap, "
            f"not noise; believe the {what} ({sig} per axis)"
        )
    elif p_above < alpha:
        believe = "residuals"
        note = (
            f"the residuals are {fig} but show no structure (no catalog effect, no feature and no smooth field "
            f"over the workspace explains any of it): believe the residuals, the measurement noise is about "
            f"{res_sig} per axis, not {sig} (a noisier instrument than stated, or an effect outside the catalog "
            "that looks like noise); the verdict does not use the stated noise"
        )
    else:
        believe = "residuals"
        note = (
            f"the residuals are only {fig}: believe the residuals, the measurements are better than stated (about "
            f"{res_sig} per axis, not {sig}); the verdict does not use the stated noise"
        )
    return NoiseCheck(source, stated, stated * ratio, ratio, float(chi2), dof, p_above, p_below,
                      believe == "both", believe, note)  # fmt: skip


def added_text(effects: list[tuple[FittedEffect, CandidateScore]], iterations: list[Iteration]) -> str:
    """``a@x, b@y added`` for the named effects; each tie term spelled out as a tie, with its advice."""
    named = [fe.label for fe, _ in effects if not fe.tied]
    parts = [f"{', '.join(named)} added"] if named else []
    for it in iterations:
        for tie, lab, why in it.resolved:
            if lab in named:
                parts.append(f"the tie {tie} of an earlier round resolved as {lab} ({why})")
    advice = {tie_label(it.decision.tied): it.decision.advice for it in iterations if it.decision.status == "ambiguous"}
    for fe, _ in effects:
        if not fe.tied:
            continue
        tips = advice.get(fe.label) or ["collect data that separates them"]
        parts.append(
            f"{' and '.join(fe.members)} are tied (the data cannot tell them apart): neither is named, the gap they "
            f"explain is added as one tie term {fe.label} (evaluated as {fe.representative}); to separate them: "
            + "; ".join(tips)
        )
    return "; ".join(parts)


def decide_verdict(iterations: list[Iteration], effects: list, max_effects: int, noise: NoiseCheck) -> tuple[str, str]:
    """``(verdict, reason)`` of the module docstring."""
    last = iterations[-1]
    text = noise.note
    done = added_text(effects, iterations)
    if last.decision.status == "named" and last.added is None:  # stopped by max_effects, a candidate decisive
        return "unexplained", f"more than {max_effects} effects would be needed; next: {last.decision.reason}"
    if last.decision.status == "ambiguous" and last.added is None:  # stopped by max_effects on a tie, not added
        stop = f"{last.decision.reason} (not added: at most {max_effects} terms)"
        return "unexplained", (f"{done}; then " if done else "") + f"{stop}; {text}"
    structure = last.structure
    if structure is not None and structure.found:
        left = f"the residuals still change systematically: {structure.describe()}"
        if effects:
            return "unexplained", f"{done}; no catalog effect explains the rest decisively: {left}; {text}"
        return "unexplained", f"no catalog effect explains the gap decisively: {left}; {text}"
    if any(fe.tied for fe, _ in effects):
        return "explained_up_to_tie", f"{done}; {text}"
    if effects:
        return "explained", f"{done}; {text}"
    return "no_gap", f"no candidate effect is significant and no structure is left; {text}"
