"""The naming rule of the camera model-gap workflow: which catalog effect, if any, the held-out
reprojection errors support beyond what noise explains.

**The test.** For a candidate model (the current model plus one effect) and the current model, the
held-out errors of the same k-fold split pair view by view (:mod:`.crossval`). The statistic is the
one-sided **Wilcoxon signed-rank test** (``scipy.stats.wilcoxon``, exact for up to 50 views) of the
per-view differences ``d_v = MSE_current(v) - MSE_candidate(v)`` (mean squared reprojection distance
per corner of held-out view ``v``): H0 "the candidate does not predict held-out views better". Views
are the unit, not corners: a view's corners share its board pose and much of the detector's error.
Under H0 the candidate's extra coefficients are fitted to noise, which makes its held-out error
*larger* on average, so the test is conservative (its false-positive rate is at most the level; the
benchmark measures it). A rank test, not a t-test: one view far outside the others (the board at the
image's edge, where a model extrapolates) would otherwise dominate the mean and the spread alike.
The p-values are Bonferroni-corrected over the candidates of the round (family-wise ``alpha``,
default 1e-3).

**The name.** Eligible candidates pass the corrected test and lower the held-out RMS. The best (the
lowest held-out error) is named when no other eligible candidate is *as good*: ``r`` is as good when
the best is not better than ``r`` by the same paired test at ``alpha_tie`` (default 0.01,
uncorrected: erring towards a tie). Tangential distortion, a thin prism and a tilted sensor are the
usual such group: to first order each is a shift of the principal point. Within a group, the best is
named **by parsimony** when it also has the fewest coefficients, alone (a hidden k3 is reproduced by
the rational model's three coefficients about as well: k3 is named, the report says which rival the
data could not rule out); when a rival with fewer coefficients is as good, or one with as few, the
group is a **tie**: none is named, the
group joins the model as one tie term fitted as its best member, and the verdict says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.camera.catalog import CameraEffect
from plugins.model_gap.camera.crossval import CrossValidation

F64 = NDArray[np.float64]

__all__ = ["CandidateScore", "Decision", "PairedTest", "decide", "paired_gain", "score_candidates"]


@dataclass(frozen=True)
class PairedTest:
    """One-sided Wilcoxon signed-rank test that model *new* predicts held-out views better than *ref*."""

    p_value: float
    statistic: float  # W+: the sum of the ranks of the views the new model predicts better
    n_views: int
    n_better: int
    mean_gain_px2: float  # mean over views of MSE_ref - MSE_new, px^2 per corner


def paired_gain(ref: CrossValidation, new: CrossValidation) -> PairedTest:
    """The paired test of *new* against *ref* over their held-out views (the same folds)."""
    from scipy.stats import wilcoxon

    n = np.maximum(ref.n_points, 1)
    d = ref.sse / n - new.sse / n
    better = int(np.sum(d > 0))
    if np.all(np.abs(d) <= 1e-15 * (ref.sse / n).max(initial=1.0)):
        return PairedTest(1.0, 0.0, len(d), better, 0.0)
    res = wilcoxon(d, alternative="greater", zero_method="zsplit")
    return PairedTest(float(res.pvalue), float(res.statistic), len(d), better, float(d.mean()))


@dataclass(frozen=True)
class CandidateScore:
    """One candidate of a round: its held-out RMS, the paired test against the current model, the
    Bonferroni-corrected p-value and whether it is eligible (and if not, why)."""

    effect: CameraEffect
    heldout_rms_px: float
    gain_px: float  # current held-out RMS - this one's
    test: PairedTest
    p_corrected: float
    eligible: bool
    reason: str


def score_candidates(
    current: CrossValidation, candidates: Sequence[tuple[CameraEffect, CrossValidation]], alpha: float
) -> list[CandidateScore]:
    """Every candidate's score against *current* (module docstring), in the order given."""
    m = max(len(candidates), 1)
    out = []
    for effect, cv in candidates:
        finite = bool(np.all(np.isfinite(cv.sse)))
        test = paired_gain(current, cv) if finite else PairedTest(1.0, 0.0, len(cv.sse), 0, float("nan"))
        p_corr = min(1.0, test.p_value * m)
        gain = current.rms_px - cv.rms_px
        if not finite:
            eligible, reason = False, "OpenCV's fit failed in a fold (the model cannot be fitted to these views)"
        elif p_corr >= alpha:
            eligible, reason = False, f"held-out gain within the noise (p = {p_corr:.2g} >= alpha = {alpha:g})"
        elif gain <= 0:
            eligible, reason = False, "the held-out RMS does not drop"
        else:
            eligible, reason = True, f"held-out views predicted better (p = {p_corr:.2g} < {alpha:g})"
        out.append(CandidateScore(effect, cv.rms_px, gain, test, p_corr, eligible, reason))
    return out


@dataclass(frozen=True)
class Decision:
    """A round's outcome: the effect named (None: none), or the tie group added as one term (its
    ``representative`` fitted), the rivals a parsimony choice could not rule out, and why."""

    named: CameraEffect | None
    tie: tuple[CameraEffect, ...] = ()
    representative: CameraEffect | None = None
    parsimony_over: tuple[CameraEffect, ...] = ()
    reason: str = ""
    pair_p_values: dict[str, float] = field(default_factory=dict)

    @property
    def added(self) -> CameraEffect | None:
        """The effect whose coefficients join the model: the named one or the tie's representative."""
        return self.named or self.representative


def decide(scores: Sequence[CandidateScore], cvs: dict[str, CrossValidation], alpha_tie: float = 0.01) -> Decision:
    """The naming rule (module docstring) over one round's *scores*; *cvs* maps effect names to their
    cross-validations."""
    eligible = [s for s in scores if s.eligible]
    if not eligible:
        return Decision(None, reason="no candidate predicts held-out views better than the noise explains")
    best = min(eligible, key=lambda s: s.heldout_rms_px)
    pair_p = {
        s.effect.name: paired_gain(cvs[s.effect.name], cvs[best.effect.name]).p_value for s in eligible if s is not best
    }
    group = [best] + [s for s in eligible if s is not best and pair_p[s.effect.name] >= alpha_tie]
    if len(group) == 1:
        why = f"{best.effect.name} predicts held-out views best (p = {best.p_corrected:.2g})"
        if pair_p:
            why += ", better than every other eligible candidate (paired p < " + f"{alpha_tie:g})"
        return Decision(best.effect, reason=why, pair_p_values=pair_p)
    fewest = min(s.effect.n_params for s in group)
    simplest = [s for s in group if s.effect.n_params == fewest]
    names = ", ".join(s.effect.name for s in group)
    if len(simplest) == 1 and simplest[0] is best:
        rivals = tuple(s.effect for s in group if s is not best)
        why = (
            f"{best.effect.name} named by parsimony: it predicts held-out views best and has the fewest "
            f"coefficients ({fewest}); {names} cannot be told apart (paired p >= {alpha_tie:g})"
        )
        return Decision(best.effect, parsimony_over=rivals, reason=why, pair_p_values=pair_p)
    rep = best.effect
    tied = tuple(s.effect for s in group)
    why = (
        f"{' | '.join(s.effect.name for s in group)} are tied (the held-out views cannot tell them apart, "
        f"paired p >= {alpha_tie:g}): none is named; the gap they explain is added "
        f"as one tie term fitted as {rep.name}; views near the image corners and strongly tilted separate them"
    )
    return Decision(None, tie=tied, representative=rep, reason=why, pair_p_values=pair_p)
