"""One round of the model-gap loop as data: the model's gap (:class:`Comparison`) and what the
round found and did (:class:`Iteration`). Produced by plugins.model_gap.core.workflow, read by the
verdict, the report and the plots."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plugins.model_gap.core.interfaces import FittedEffect, Signature
from plugins.model_gap.core.localise import FeatureGap
from plugins.model_gap.core.selection import CandidateScore, Decision
from plugins.model_gap.core.structure import StructureTest


@dataclass
class Comparison:
    """The gap of one model: physical residual statistics and the chi-square test (SI units)."""

    rms: float  # 3-D RMS over samples
    max: float  # largest per-sample norm
    rms_axis: list[float]
    mean_axis: list[float]
    chi2: float  # whitened residual sum of squares
    dof: int  # residuals minus fitted parameters (rank of the model's Jacobian)
    chi2_p: float  # P(chi2(dof) >= chi2): small when the residuals are larger than the stated noise
    consistent: bool
    cv_rms: float  # held-out (k-fold) RMS
    noise_rms: float  # 3-D RMS the noise alone would give

    @property
    def ratio_to_noise(self) -> float:
        """The residuals "x the noise": ``sqrt(chi2 / dof)``, dof = residuals - fitted parameters.

        The a-posteriori sigma over the stated one; 1 for a correct model and noise. (The in-sample RMS
        over the noise floor is smaller by ``sqrt(dof / residuals)``: the fit takes one noise
        component per parameter.)
        """
        return float(np.sqrt(self.chi2 / self.dof)) if self.dof > 0 else np.inf


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
    added_score: CandidateScore | None = None  # a tie term: the representative's score
    signature: Signature | None = None
    # (N, m) physical contribution of the added effect (linearised, this round's fit): in full, and the
    # part the model before it (baseline calibration + earlier effects) cannot absorb -- what the
    # residuals can show, since the calibration takes the rest
    contribution: np.ndarray | None = None
    identifiable: np.ndarray | None = None
    model_file: str | None = None
    # earlier effects dropped after this round's addition: (label, BIC gain given the others < 0)
    removed: list[tuple[str, float]] = field(default_factory=list)
    # tie terms of earlier rounds resolved after this round's addition: (tie label, member now named, why)
    resolved: list[tuple[str, str, str]] = field(default_factory=list)
    # what systematic residual this round's model leaves (noise-independent F-tests; None: not tested)
    structure: StructureTest | None = None
