"""Result types of every point-cloud matcher: the estimate, its quality, its uncertainty, a verdict.

Convention for ``T_match`` (seed 000, method A and B)
-----------------------------------------------------
``T_match`` maps points of the CURRENT capture onto the TEMPLATE capture::

    p_template = T_match @ p_current          # both in their camera (cloud) frames

i.e. ``T_match = ICP(P_current, P_template)`` of seed 000 (source = current, target = template), and for
the feature-frame method ``T_match = Frame_template @ inv(Frame_current)``. In vgr's frame notation,
with ``T_camT_part`` the part pose in the template capture and ``T_camC_part`` the part pose in the
current capture, ``T_match = T_camT_part @ inv(T_camC_part)``: the pose of the current camera frame in
the template camera frame *as seen by the part*. Units: metres.

Verdicts
--------
``ok``         a single pose explains the data and every quality test passed; ``T_match`` is set.
``ambiguous``  the data admit more than one pose: two or more distinct hypotheses score within the
               ambiguity gap (symmetric part), or a direction is not determined (e.g. a flat plate
               that can slide in its plane) beyond the uncertainty limits. ``T_match`` is ``None``;
               the candidates are in ``hypotheses``. Never use it to move a robot.
``failed``     no trustworthy estimate (bad input, too little overlap, wrong part, part missing).
               ``T_match`` is ``None``; ``reasons`` says why.

Uncertainty
-----------
``hessian`` is ``J^T J`` of the point-to-plane residuals (template normals; plus the weighted
contour edge rows where the edge term ran) at the optimum, for the left perturbation
``T' = exp(xi) @ T_match`` with the twist ``xi = (v, w)`` expressed in the template frame at its
origin. ``covariance`` is the cluster-robust covariance of that estimate times the calibration
factor squared (see uncertainty.py: ``s^2 inv(hessian)`` understated the errors on simulated
captures by up to 10x). ``sigma_translation_m`` / ``sigma_rotation_rad`` are the per-axis one-sigma values of the
same twist moved to ``uncertainty_center`` (the centroid of the matched current points, in the
template frame) so that they read "how well is the part located": translation of the part's centre
along the template camera's x, y, z and rotation about those axes through the centre.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from engine import transforms as tf
from engine.plain_data import plain

Verdict = Literal["ok", "ambiguous", "failed"]


@dataclass
class WeakDirection:
    """A direction of the 6-D pose that the data determine poorly (eigen-analysis of the Hessian).

    ``kind`` is ``translation``, ``rotation`` or ``screw`` (mixed); ``axis`` is a unit vector in the
    template frame (for rotations through ``uncertainty_center``). ``ratio`` is the eigenvalue over
    the largest one after scaling rotations by the cloud's radius (1 = as well determined as the
    best direction, 0 = not at all). ``sigma`` is the one-sigma along it (m or rad).
    """

    kind: Literal["translation", "rotation", "screw"]
    axis: np.ndarray
    ratio: float
    sigma: float

    def describe(self) -> str:
        unit = "mm" if self.kind == "translation" else "deg"
        value = self.sigma * 1e3 if self.kind == "translation" else float(np.degrees(self.sigma))
        ax = ", ".join(f"{a:+.2f}" for a in self.axis)
        return f"weak {self.kind} along ({ax}): 1-sigma {value:.3g} {unit}, stiffness ratio {self.ratio:.1e}"


@dataclass
class Hypothesis:
    """One candidate ``T_match`` with its scores (lower ``score`` is better).

    ``score`` is the truncated mean distance (m) from the current points to the template,
    ``fitness`` the fraction of current points within the inlier distance, ``inlier_rmse`` their RMS
    distance (m), ``source`` the generator (e.g. ``planar:flip=0:angle=35``, ``fpfh_ransac:seed=3``).
    """

    T_match: np.ndarray
    score: float
    fitness: float
    inlier_rmse: float
    source: str = ""


@dataclass
class RegistrationResult:
    """Outcome of one registration (fine, global or feature-frame). See the module docstring."""

    verdict: Verdict
    method: str
    T_match: np.ndarray | None = None
    reasons: list[str] = field(default_factory=list)
    fitness: float = 0.0
    inlier_rmse: float = float("nan")
    score: float = float("nan")
    hessian: np.ndarray | None = None
    covariance: np.ndarray | None = None
    uncertainty_center: np.ndarray | None = None
    sigma_translation_m: np.ndarray | None = None
    sigma_rotation_rad: np.ndarray | None = None
    weak_directions: list[WeakDirection] = field(default_factory=list)
    hypotheses: list[Hypothesis] = field(default_factory=list)
    score_gap: float = float("nan")
    iterations: int = 0
    converged: bool = False
    timings_s: dict[str, float] = field(default_factory=dict)
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def usable(self) -> bool:
        """True only for verdict ``ok`` (a pose the robot may act on, subject to its own limits)."""
        return self.verdict == "ok" and self.T_match is not None

    @property
    def best(self) -> Hypothesis | None:
        """Best-ranked hypothesis (also for ambiguous results), or None."""
        return self.hypotheses[0] if self.hypotheses else None

    def covariance_at(self, point: np.ndarray) -> np.ndarray | None:
        """6x6 covariance of the twist ``(v, w)`` moved to *point* (template frame, m): the
        translation block is then the uncertainty of where that point of the part is."""
        if self.covariance is None:
            return None
        Ad = tf.adjoint(tf.T_from_Rt(np.eye(3), -np.asarray(point, dtype=float).reshape(3)))
        return Ad @ self.covariance @ Ad.T

    def sigma_mm_deg(self) -> dict[str, float]:
        """Per-axis one-sigma for people: ``x_mm, y_mm, z_mm, rx_deg, ry_deg, rz_deg``."""
        if self.sigma_translation_m is None or self.sigma_rotation_rad is None:
            return {}
        t = self.sigma_translation_m * 1e3
        r = np.degrees(self.sigma_rotation_rad)
        keys = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")
        return dict(zip(keys, [*t.tolist(), *r.tolist()], strict=True))

    def summary(self) -> str:
        """One line for logs and CLI output (mm / degrees)."""
        parts = [f"{self.method}: {self.verdict}"]
        if np.isfinite(self.inlier_rmse):
            parts.append(f"fitness {self.fitness:.3f}, rmse {self.inlier_rmse * 1e3:.3f} mm")
        s = self.sigma_mm_deg()
        if s:
            parts.append("sigma " + ", ".join(f"{k} {v:.3g}" for k, v in s.items()))
        if np.isfinite(self.score_gap):
            parts.append(f"gap {self.score_gap:.3f}")
        if self.reasons:
            parts.append("; ".join(self.reasons))
        return " | ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary of every field (arrays become lists, NaN becomes None)."""
        return plain(asdict(self), nan_as_none=True)

    def to_json(self, **kwargs: Any) -> str:
        return json.dumps(self.to_dict(), **kwargs)


def failed(method: str, *reasons: str, **details: Any) -> RegistrationResult:
    """A ``failed`` result with its reasons (no estimate)."""
    return RegistrationResult(verdict="failed", method=method, reasons=list(reasons), details=dict(details))
