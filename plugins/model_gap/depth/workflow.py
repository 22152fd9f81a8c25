"""The depth model-gap loop: screen, compare, name, add, repeat; then the verdict.

0. **Screen.** Gross errors (mixed and flying pixels) are flagged against the richest model with a
   robust loss and left out (:func:`.fitting.screen`, against the noise law estimated robustly); the
   noise ``sigma`` the fits weight by is the sensor's stated ``sigma(z)`` or that law.
1. **Compare.** The baseline (the range predicted from the target: no coefficient with known poses,
   each capture's plane with ``target = "fit"``) is scored on held-out captures by k-fold
   cross-validation (:mod:`.crossval`).
2. **Name.** Every catalog effect not yet in the model is added in turn and cross-validated on the
   same folds; the camera workflow's naming rule (:mod:`plugins.model_gap.camera.selection`: a paired
   Wilcoxon test over held-out captures, Bonferroni over the round, ties and parsimony) names one,
   adds a tie term, or stops.
3. **Repeat** until nothing is eligible or ``max_effects`` terms are in.
4. **Verdict.** The residuals of the final model fitted to all captures are tested for structure
   (:mod:`.structure`: sign flips of whole captures, no noise estimate), and, when the noise is
   stated, their RMS against it (believed to ``noise_trust``): ``no_gap``, ``explained``,
   ``explained_up_to_tie`` or ``unexplained`` (structure or excess noise left, or the effect limit
   reached with a candidate still eligible). When structure is left, each added term's **share** of
   what the model without it left beyond the noise is reported, and a term below ``min_share`` is
   taken out again: it does not explain the gap, it only nibbles at it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.camera.selection import CandidateScore, Decision, decide, score_candidates
from plugins.model_gap.depth.catalog import CATALOG, DEFAULT_WIGGLE_PERIOD_M, DepthEffect, feature_matrix
from plugins.model_gap.depth.crossval import DepthCrossValidation, capture_folds, cross_validate
from plugins.model_gap.depth.data import DepthCaptures, DepthGapInputError, Pixels, identifiable_share, prepare
from plugins.model_gap.depth.fitting import DepthFit, Screen, fit_model, residuals_under, screen
from plugins.model_gap.depth.structure import DepthStructure, structure_of
from plugins.model_gap.naming_loop import LabelledTerm, limit_or_structure, name_effects, named_verdict
from plugins.model_gap.selection_options import SelectionOptions

F64 = NDArray[np.float64]

__all__ = ["MIN_CAPTURES", "AddedTerm", "DepthGapConfig", "DepthGapResult", "GapRound", "run_depth_gap"]

MIN_CAPTURES = 6
IDENTIFIABLE = 1e-6  # an effect whose columns a plane fit absorbs to within this share is not tested


@dataclass(frozen=True)
class DepthGapConfig(SelectionOptions):
    """The workflow's options (module docstring; the selection's: :class:`.SelectionOptions`)."""

    target: str = "auto"  # "known" (every capture's pose given), "fit" (a plane per capture), "auto"
    outlier_alpha: float = 0.01
    noise_trust: float = 2.0
    min_share: float = 0.3
    wiggle_period_m: float = DEFAULT_WIGGLE_PERIOD_M
    catalog: tuple[DepthEffect, ...] = CATALOG

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (0.0 <= self.outlier_alpha < 0.5):
            raise ValueError(f"outlier_alpha must be in [0, 0.5) (0: no screen), got {self.outlier_alpha}")
        if not self.noise_trust >= 1.0:
            raise ValueError(f"noise_trust must be >= 1, got {self.noise_trust}")
        if not (0.0 <= self.min_share <= 1.0):
            raise ValueError(f"min_share must be in [0, 1], got {self.min_share}")
        if not (np.isfinite(self.wiggle_period_m) and self.wiggle_period_m > 0):
            raise ValueError(f"wiggle_period_m must be > 0, got {self.wiggle_period_m}")


@dataclass(frozen=True)
class GapRound:
    """One round: the current model's held-out RMS (mm), every candidate's score, the decision."""

    iteration: int
    current_heldout_rms_mm: float
    scores: list[CandidateScore]
    decision: Decision


@dataclass
class AddedTerm(LabelledTerm):
    """An effect added to the model: named (``tied_with`` empty) or a tie term fitted as ``effect``;
    ``share``: of what the model without it leaves beyond the noise, the part it explains."""

    effect: DepthEffect
    tied_with: tuple[DepthEffect, ...]
    parsimony_over: tuple[DepthEffect, ...]
    iteration: int
    heldout_rms_before_mm: float
    heldout_rms_after_mm: float
    p_corrected: float
    share: float = float("nan")
    dropped: bool = False


@dataclass
class DepthGapResult:
    """Everything the report needs (:mod:`.report`)."""

    verdict: str
    reason: str
    pixels: Pixels
    screen: Screen
    rounds: list[GapRound]
    added: list[AddedTerm]
    baseline_cv: DepthCrossValidation
    final_cv: DepthCrossValidation
    final_fit: DepthFit
    rms_before_mm: float
    rms_after_mm: float
    structure_before: DepthStructure
    structure_after: DepthStructure
    noise: dict[str, Any]
    config: DepthGapConfig
    untestable: dict[str, float]
    notes: list[str] = field(default_factory=list)
    flagged_per_capture: list[int] = field(default_factory=list)  # gross-error pixels left out, by capture

    @property
    def named(self) -> list[str]:
        return [a.effect.name for a in self.added if not a.tied_with and not a.dropped]

    @property
    def kept(self) -> list[AddedTerm]:
        return [a for a in self.added if not a.dropped]


def _testable(px: Pixels, cfg: DepthGapConfig) -> tuple[list[DepthEffect], dict[str, float], list[str]]:
    """The catalog effects a per-capture plane fit does not absorb, each one's share left, notes."""
    if px.target == "known":
        return list(cfg.catalog), {}, []
    out, untestable, notes = [], {}, []
    for e in cfg.catalog:
        share = float(np.max(identifiable_share(px, feature_matrix([e], px.r_ref, px.x, px.y, cfg.wiggle_period_m))))
        if share < IDENTIFIABLE:
            untestable[e.name] = share
            notes.append(f"{e.name} not tested: the per-capture plane fit absorbs it (give the target's pose)")
        else:
            out.append(e)
            if share < 0.5:
                notes.append(f"{e.name}: only {100 * share:.2g}% of it is left after the per-capture plane fit")
    return out, untestable, notes


def _rms_mm(residual: F64) -> float:
    return float(1e3 * np.sqrt(np.mean(residual**2))) if len(residual) else float("nan")


def _loop(px: Pixels, catalog: list[DepthEffect], w: F64, folds: list, cfg: DepthGapConfig) -> tuple[Any, ...]:
    """Rounds of the module docstring: (rounds, added, effects, baseline cv, final cv, still eligible)."""
    period = cfg.wiggle_period_m

    def evaluate(current: DepthCrossValidation, effects: list[DepthEffect], candidates: list[DepthEffect]) -> Any:
        cvs = {e.name: cross_validate(px, (*effects, e), folds, w, period) for e in candidates}
        pairs = cast(Any, [(e, cvs[e.name]) for e in candidates])  # (the selection reads sse, n_points, rms_px)
        scores = score_candidates(cast(Any, current), pairs, cfg.alpha)
        return scores, decide(scores, cast(Any, cvs), cfg.alpha_tie), cvs

    baseline_cv = cross_validate(px, (), folds, w, period)
    run = name_effects(catalog, baseline_cv, cfg.max_effects, evaluate, lambda cv: cv.rms_mm, GapRound, AddedTerm)
    return run.rounds, run.added, run.effects, run.baseline, run.final, run.still_eligible


def _noise(px: Pixels, sc: Screen, residual: F64, captures: DepthCaptures) -> dict[str, Any]:
    """The noise the final residuals show: per capture its robust scale at its median depth, the law
    ``a + b z^2`` fitted over depth bins (:func:`.fitting.sigma_law`), and with a stated law the
    residuals' RMS over it."""
    from plugins.model_gap.depth.fitting import capture_scale, sigma_law

    s = capture_scale(px, residual)
    z = np.array([np.median(px.z_ref[px.capture == k]) for k in range(px.n_captures)])
    law = sigma_law(px.z_ref, residual)
    out: dict[str, Any] = {
        "source": sc.sigma_source,
        "per_capture": [
            {"capture": px.names[k], "median_depth_mm": float(1e3 * z[k]), "sigma_mm": float(1e3 * s[k])}
            for k in range(px.n_captures)
        ],
        "estimated_law": {"sigma_const_mm": 1e3 * law.const_m, "sigma_quad_per_m_mm": 1e3 * law.quad_per_m},
        "stated_law": None,
        "rms_over_stated": None,
    }
    if captures.sigma is not None:
        out["stated_law"] = {
            "sigma_const_mm": 1e3 * captures.sigma.const_m,
            "sigma_quad_per_m_mm": 1e3 * captures.sigma.quad_per_m,
        }
        out["rms_over_stated"] = float(np.sqrt(np.mean((residual / captures.sigma(px.z_ref)) ** 2)))
    return out


def _shares(added: list[AddedTerm], noise_var_m2: float) -> None:
    for a in added:
        before, after = (a.heldout_rms_before_mm / 1e3) ** 2, (a.heldout_rms_after_mm / 1e3) ** 2
        gap = before - noise_var_m2
        a.share = float(np.clip((before - after) / gap, 0.0, 1.0)) if gap > 0 else 1.0


def _verdict(
    kept: list[AddedTerm], after: DepthStructure, noise: dict[str, Any], still_eligible: bool, cfg: DepthGapConfig
) -> tuple[str, str]:
    names = ", ".join(a.label for a in kept) or "nothing"
    left = limit_or_structure(names, after, still_eligible, cfg, "captures")
    if left is not None:
        return left
    ratio = noise["rms_over_stated"]
    if ratio is not None and ratio > cfg.noise_trust:
        return "unexplained", (
            f"added {names}; the residuals are {ratio:.2f}x the stated noise (believed to {cfg.noise_trust:g}x): "
            "an effect outside the catalog, or the stated noise is wrong (give none to have it estimated)"
        )
    return named_verdict(kept, names, "captures")


def _final(px: Pixels, effects: list[DepthEffect], w: F64, cfg: DepthGapConfig) -> tuple[DepthFit, F64, DepthStructure]:
    fit = fit_model(px, np.ones(len(px.capture), dtype=bool), effects, w, cfg.wiggle_period_m)
    residual = residuals_under(px, fit, w, cfg.wiggle_period_m)
    return fit, residual, structure_of(px, residual, cfg.seed)


def run_depth_gap(captures: DepthCaptures, config: DepthGapConfig | None = None) -> DepthGapResult:
    """The workflow of the module docstring on depth captures of a flat target."""
    cfg = config or DepthGapConfig()
    all_px = prepare(captures, cfg.target)
    if all_px.n_captures < max(MIN_CAPTURES, cfg.folds):
        left_out = ""
        if captures.rejected:
            left_out = f" ({len(captures.rejected)} left out: {captures.rejected[0][0]}: {captures.rejected[0][1]})"
        raise DepthGapInputError(
            f"{all_px.n_captures} usable captures of the target{left_out}: the depth gap needs at least "
            f"{max(MIN_CAPTURES, cfg.folds)} for its cross-validation over captures, and "
            f"{_captures_to_name(len(cfg.catalog), cfg.alpha)} to name an effect at alpha {cfg.alpha:g} "
            "(16-30 recommended, at several distances and tilts)"
        )
    catalog, untestable, notes = _testable(all_px, cfg)
    sc = screen(all_px, catalog, captures.sigma, cfg.outlier_alpha, cfg.wiggle_period_m)
    px = all_px.take(sc.inlier)
    w = 1.0 / sc.sigma[sc.inlier]
    folds = capture_folds(px.n_captures, cfg.folds, cfg.seed)
    rounds, added, effects, baseline_cv, final_cv, still_eligible = _loop(px, catalog, w, folds, cfg)
    _, base_res, before = _final(px, [], w, cfg)
    fit, residual, after = _final(px, effects, w, cfg)
    noise = _noise(px, sc, residual, captures)
    _shares(added, float(np.mean(sc.sigma[sc.inlier] ** 2)))
    if after.p_value < cfg.alpha and any(a.share < cfg.min_share for a in added):
        for a in added:
            a.dropped = a.share < cfg.min_share
        kept_effects = [a.effect for a in added if not a.dropped]
        notes.append(
            "taken out again (structure is left and each explains less than "
            f"{cfg.min_share:.0%} of what the model without it leaves): "
            + ", ".join(a.label for a in added if a.dropped)
        )
        final_cv = cross_validate(px, kept_effects, folds, w, cfg.wiggle_period_m)
        fit, residual, after = _final(px, kept_effects, w, cfg)
        noise = _noise(px, sc, residual, captures)
    verdict, reason = _verdict([a for a in added if not a.dropped], after, noise, still_eligible, cfg)
    if verdict == "no_gap" and untestable:
        reason += f" (not tested, the plane fit absorbs them: {', '.join(untestable)})"
    if sc.n_flagged:
        reason += f"; {sc.n_flagged} gross-error pixels left out (|residual| > {sc.threshold_sigma:.1f} sigma)"
    notes += _power_notes(px.n_captures, len(catalog), cfg.alpha)
    return DepthGapResult(
        verdict, reason, px, sc, rounds, added, baseline_cv, final_cv, fit, _rms_mm(base_res), _rms_mm(residual),
        before, after, noise, cfg, untestable, notes,
        np.bincount(all_px.capture[~sc.inlier], minlength=all_px.n_captures).astype(int).tolist(),
    )  # fmt: skip


def _captures_to_name(n_candidates: int, alpha: float) -> int:
    """The fewest captures whose smallest corrected p-value (``n_candidates 2^-n``) is below *alpha*."""
    return int(np.floor(np.log2(max(n_candidates, 1) / alpha))) + 1


def _power_notes(n_captures: int, n_candidates: int, alpha: float) -> list[str]:
    """The smallest corrected p-value n captures give, when it cannot reach alpha."""
    p_min = max(n_candidates, 1) * 0.5**n_captures
    if p_min >= alpha:
        need = _captures_to_name(n_candidates, alpha)
        return [
            f"with {n_captures} captures the smallest corrected p-value the paired test can reach is {p_min:.2g} >= "
            f"alpha {alpha:g}: no effect can be named; use at least {need} captures"
        ]
    return []
