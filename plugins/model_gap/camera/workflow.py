"""The camera model-gap loop: compare, name, add, repeat; then the verdict.

1. **Compare.** The baseline camera (pinhole + Brown's k1, k2: :data:`.catalog.BASELINE`) is fitted by
   ``cv2.calibrateCamera`` to every view; k-fold cross-validation over views gives each view's
   held-out reprojection error (:mod:`.crossval`).
2. **Name.** Every catalog effect not yet in the model is added to it in turn and cross-validated
   on the same folds; the naming rule (:mod:`.selection`: a paired Wilcoxon test over held-out views,
   Bonferroni over the round, ties and parsimony) names one, adds a tie term, or stops.
3. **Repeat** until nothing is eligible or ``max_effects`` terms are in.
4. **Verdict.** The residuals of the final model fitted to all views are tested for structure left
   (:mod:`.structure`: sign flips of whole views, no noise estimate): ``no_gap`` (nothing added, no
   structure), ``explained`` (every added term named, no structure), ``explained_up_to_tie`` (a tie
   term added, no structure), ``unexplained`` (structure left, or the effect limit reached with a
   candidate still eligible): the exit codes of ``vgr gap`` (:data:`plugins.model_gap.verdicts.VERDICT_EXIT_CODES`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from plugins.calibration.boards.detect import Detection
from plugins.model_gap.camera.catalog import BASELINE, BOARD_POINTS, CATALOG, CameraEffect, free_coefficients
from plugins.model_gap.camera.crossval import CrossValidation, cross_validate, view_folds
from plugins.model_gap.camera.fitting import CameraModelFit, fit_nested, fit_views
from plugins.model_gap.camera.selection import CandidateScore, Decision, decide, score_candidates
from plugins.model_gap.camera.structure import StructureTest, neighbour_structure, residual_structure
from plugins.model_gap.naming_loop import LabelledTerm, limit_or_structure, name_effects, named_verdict
from plugins.model_gap.selection_options import SelectionOptions

__all__ = ["MIN_VIEWS", "AddedTerm", "CameraGapConfig", "CameraGapResult", "GapRound", "Structure", "run_camera_gap"]

MIN_VIEWS = 6


@dataclass(frozen=True)
class CameraGapConfig(SelectionOptions):
    """The workflow's options: family-wise level per round, the tie level, folds, seed, effect limit
    (:class:`.SelectionOptions`), the catalog."""

    catalog: tuple[CameraEffect, ...] = CATALOG


@dataclass(frozen=True)
class GapRound:
    """One round: the current model's held-out RMS, every candidate's score, the decision."""

    iteration: int
    current_heldout_rms_px: float
    scores: list[CandidateScore]
    decision: Decision


@dataclass(frozen=True)
class AddedTerm(LabelledTerm):
    """An effect added to the model: named (``tied_with`` empty) or a tie term fitted as ``effect``."""

    effect: CameraEffect
    tied_with: tuple[CameraEffect, ...]
    parsimony_over: tuple[CameraEffect, ...]
    iteration: int
    heldout_rms_before_px: float
    heldout_rms_after_px: float
    p_corrected: float


@dataclass(frozen=True)
class Structure:
    """Both structure tests of one model's residuals (:mod:`.structure`) and their combined p-value
    (the smaller, Bonferroni x 2)."""

    image_field: StructureTest
    neighbours: StructureTest

    @property
    def p_value(self) -> float:
        return min(1.0, 2.0 * min(self.image_field.p_value, self.neighbours.p_value))

    def describe(self) -> str:
        """Where the structure is, in words (the test with the smaller p-value)."""
        if self.image_field.p_value <= self.neighbours.p_value:
            at = self.image_field.where[0]["cell_centre_px"] if self.image_field.where else None
            return f"a residual field fixed in the image, largest near pixel {at}"
        at = self.neighbours.where[0]["view"] if self.neighbours.where else None
        return f"residuals smooth over the board within views (neighbouring corners agree; most in {at})"

    def advice(self) -> str:
        """What to measure to find the effect (the test with the smaller p-value)."""
        if self.image_field.p_value <= self.neighbours.p_value:
            return "add views that reach the image's corners and edges; a lens outside the catalog (fisheye) fits there"
        return (
            "check the board's flatness (a straightedge, or the board on a flat plate) and its print scale, take the "
            "images at rest (a camera moving during a rolling-shutter exposure), and sharper, evenly lit images "
            "(a detector whose errors agree between neighbouring corners)"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "p_value": self.p_value,
            "image_field": self.image_field.to_dict(),
            "neighbours": self.neighbours.to_dict(),
        }


def structure_of(views: Sequence[Detection], fit: CameraModelFit, size: tuple[int, int], seed: int) -> Structure:
    """Both structure tests on *fit*'s in-sample residuals."""
    return Structure(residual_structure(views, fit.residuals, size, seed), neighbour_structure(views, fit.residuals))


@dataclass
class CameraGapResult:
    """Everything the report needs (:mod:`.report`)."""

    verdict: str
    reason: str
    size: tuple[int, int]
    views: list[Detection]
    rounds: list[GapRound]
    added: list[AddedTerm]
    baseline_cv: CrossValidation
    final_cv: CrossValidation
    baseline_fit: CameraModelFit
    final_fit: CameraModelFit
    structure_before: Structure
    structure_after: Structure
    config: CameraGapConfig
    notes: list[str] = field(default_factory=list)

    @property
    def named(self) -> list[str]:
        return [a.effect.name for a in self.added if not a.tied_with]


def _round(
    views: Sequence[Detection],
    size: tuple[int, int],
    current: CrossValidation,
    candidates: Sequence[CameraEffect],
    folds: Sequence[np.ndarray],
    cfg: CameraGapConfig,
) -> tuple[list[CandidateScore], Decision, dict[str, CrossValidation]]:
    cvs: dict[str, CrossValidation] = {}
    for effect in candidates:
        free = current.free | set(effect.coefficients)
        try:
            cvs[effect.name] = cross_validate(views, size, free, folds, current)
        except Exception:  # OpenCV refusing (cv2.error) or a held-out pose failing: the candidate is out
            n = len(views)
            cvs[effect.name] = CrossValidation(free, np.full(n, np.inf), current.n_points, current.residuals, ())
    scores = score_candidates(current, [(e, cvs[e.name]) for e in candidates], cfg.alpha)
    return scores, decide(scores, cvs, cfg.alpha_tie), cvs


def _verdict(added: list[AddedTerm], after: Structure, still_eligible: bool, cfg: CameraGapConfig) -> tuple[str, str]:
    names = ", ".join(a.label for a in added) or "nothing"
    return limit_or_structure(names, after, still_eligible, cfg, "views") or named_verdict(added, names, "views")


def run_camera_gap(
    views: Sequence[Detection], size: tuple[int, int], config: CameraGapConfig | None = None
) -> CameraGapResult:
    """The workflow of the module docstring on board detections of one camera."""
    cfg = config or CameraGapConfig()
    views = list(views)
    if len(views) < max(MIN_VIEWS, cfg.folds):
        raise ValueError(
            f"{len(views)} views with the board: the camera gap needs at least {max(MIN_VIEWS, cfg.folds)} "
            "(15-30 recommended) for its cross-validation over views"
        )
    folds = view_folds(len(views), cfg.folds, cfg.seed)
    catalog, notes = _testable(cfg.catalog, views)
    try:
        baseline_cv = cross_validate(views, size, BASELINE, folds)
    except Exception as exc:  # cv2.error: e.g. every view frontal and coplanar
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"the baseline camera cannot be fitted to these views ({msg}): tilt the board") from None
    run = name_effects(
        catalog, baseline_cv, cfg.max_effects,
        lambda current, _effects, candidates: _round(views, size, current, candidates, folds, cfg),
        lambda cv: cv.rms_px, GapRound, AddedTerm,
    )  # fmt: skip
    rounds, added, effects, current, still_eligible = run.rounds, run.added, run.effects, run.final, run.still_eligible
    baseline_fit = fit_views(views, size, BASELINE)
    free = free_coefficients(effects)
    final_fit = (
        baseline_fit if not effects else fit_views(views, size, free) if BOARD_POINTS in free else
        fit_nested(views, size, free, baseline_fit)
    )  # fmt: skip
    before = structure_of(views, baseline_fit, size, cfg.seed)
    after_test = structure_of(views, final_fit, size, cfg.seed)
    verdict, reason = _verdict(added, after_test, still_eligible, cfg)
    notes += _notes(len(views), len(catalog), cfg.alpha)
    return CameraGapResult(
        verdict, reason, size, views, rounds, added, baseline_cv, current, baseline_fit, final_fit,
        before, after_test, cfg, notes,
    )  # fmt: skip


def _testable(catalog: Sequence[CameraEffect], views: Sequence[Detection]) -> tuple[list[CameraEffect], list[str]]:
    """The catalog effects the views can test, and a note for each left out."""
    from plugins.model_gap.camera.fitting import fixed_board_point

    out, notes = [], []
    for e in catalog:
        if e.releases_board:
            try:
                fixed_board_point(views)
            except ValueError as exc:
                notes.append(f"{e.name} not tested: {exc}")
                continue
        out.append(e)
    return out, notes


def _notes(n_views: int, n_candidates: int, alpha: float) -> list[str]:
    """What the user should know about the data's power: the smallest corrected p-value n views give."""
    p_min = n_candidates * 0.5**n_views
    if p_min >= alpha:
        need = int(np.ceil(np.log2(n_candidates / alpha)))
        return [
            f"with {n_views} views the smallest corrected p-value the paired test can reach is {p_min:.2g} >= "
            f"alpha {alpha:g}: no effect can be named; use at least {need} views"
        ]
    return []
