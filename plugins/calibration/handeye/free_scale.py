"""Hand-eye calibration with the camera's length unit unknown (``scale="free"``): a monocular or
visual-odometry camera reports its translations up to one factor ``k`` (metres = ``k`` x camera units).

1. **start**: the screw invariant of each motion pair (``consistency.estimate_unit_scale``) gives
   ``k0`` and its spread; when the motions cannot show it (pure translations, rotations about one
   axis) the result is ``failed`` with what to add;
2. **solve** at ``k0`` (the whole solver: motion checks, consensus, ML, noise estimation, verdict);
3. **profile**: ``k = k0 exp(u)``; for each ``u`` the camera translations are scaled and the ML is
   solved again with the noise and the inlier set of step 2 held (``ml.chi2_at``); a bounded scalar
   search (Brent) finds the ``u`` of least chi-square, and the curvature there gives its 1-sigma
   (``chi2(u) ~ chi2_min + (u - u*)^2 / sigma_u^2``, the profile likelihood's Fisher information);
4. **final**: the whole solver again at ``k*``; its covariance of (X, Y) gains the scale's share
   ``g g^T`` (``g`` the change of X and Y per ``sigma_u``, from the profile's fits at ``u* +- sigma_u``),
   so the reported uncertainty includes that of the scale.

Per-sample camera covariances (``noise``) are in the camera's units too: at scale ``k`` their
translation rows and columns are multiplied by ``k`` (:func:`scaled_covariances`).

The result is the solver's at ``k*`` with ``estimate["camera_scale"]`` = ``k*`` and the metrics
``camera_scale``, ``camera_scale_sd`` (and the reason saying so).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar

from engine.transforms import pose_delta
from plugins.calibration.handeye.assemble import AccuracyTargets, std_metrics
from plugins.calibration.handeye.consistency import estimate_unit_scale
from plugins.calibration.handeye.ml import MLFit, chi2_at
from plugins.calibration.handeye.problem import Setup
from plugins.calibration.handeye.validation import ValidatedSamples, validate_samples
from plugins.calibration.result import CalibrationResult

F64 = NDArray[np.float64]

__all__ = ["SolvedFit", "scaled", "scaled_covariances", "solve_free_scale"]


@dataclass(frozen=True)
class SolvedFit:
    """The ML fit behind a solver's result: its set-up, the fit and the samples it was made on."""

    setup: Setup
    fit: MLFit
    data: ValidatedSamples


# the solver with the camera's translations (and their covariances) multiplied by a scale
Solve = Callable[[float], tuple[CalibrationResult, SolvedFit | None]]


def scaled(B: ArrayLike, k: float) -> F64:
    """Camera poses with their translations multiplied by *k*."""
    out = np.array(B, dtype=float, copy=True)
    out[:, :3, 3] *= k
    return out


def scaled_covariances(covariances: ArrayLike | None, k: float) -> F64 | None:
    """Per-sample camera covariances ``(n, 6, 6)`` of translations multiplied by *k*: ``S C S`` with
    ``S = diag(k, k, k, 1, 1, 1)`` (None stays None)."""
    if covariances is None:
        return None
    c = np.asarray(covariances, dtype=float)
    if c.ndim != 3 or c.shape[1:] != (6, 6):
        return c  # (the solver's check refuses it, saying why)
    s = np.array([k, k, k, 1.0, 1.0, 1.0])
    return c * s[:, None] * s[None, :]


def _unobservable(kind: str, why: str) -> CalibrationResult:
    return CalibrationResult(
        kind=kind,  # type: ignore[arg-type]
        verdict="failed",
        reasons=[f"the camera's scale cannot be solved: {why}"],
        advice=["add poses that rotate about different axes by 20 degrees or more, with translations"],
        method="free camera scale (not solved)",
    )


def _profile(sf: SolvedFit, bound: float) -> tuple[float, float]:
    """Step 3 around the scale *sf* was solved at: ``u*`` and ``sigma_u`` (inf when the profile is flat)."""
    fit, M, B = sf.fit, sf.data.T_base_tcp, sf.data.T_cam_target
    weights = (~fit.outliers).astype(float)

    def cost(u: float) -> float:
        return chi2_at(sf.setup, M, scaled(B, np.exp(u)), fit.X, fit.Y, fit.noise, weights)[0]

    best = minimize_scalar(cost, bounds=(-bound, bound), method="bounded", options={"xatol": 1e-7})
    u, f0 = float(best.x), float(best.fun)
    sigma = float("inf")
    h = 1e-3
    for _ in range(2):  # the second pass with a step near the sigma found: a better-conditioned difference
        c2 = (cost(u + h) - 2.0 * f0 + cost(u - h)) / h**2
        if not c2 > 0.0:
            return u, float("inf")
        sigma = float(np.sqrt(2.0 / c2))
        h = min(max(sigma / 2.0, 1e-6), 0.1)
    return u, sigma


def _scale_share(sf: SolvedFit, sigma_u: float) -> F64:
    """Step 4: ``g g^T`` (12 x 12), the change of (X, Y) over one ``sigma_u`` either way of the
    scale *sf* was solved at."""
    fit, M, B = sf.fit, sf.data.T_base_tcp, sf.data.T_cam_target
    weights = (~fit.outliers).astype(float)
    ends = []
    for u in (sigma_u, -sigma_u):
        _, X, Y = chi2_at(sf.setup, M, scaled(B, np.exp(u)), fit.X, fit.Y, fit.noise, weights)
        ends.append(np.concatenate([pose_delta(X, fit.X)[0], pose_delta(Y, fit.Y)[0]]))
    g = 0.5 * (ends[0] - ends[1])
    return np.outer(g, g)


def solve_free_scale(
    solve: Solve, kind: str, T_base_tcp: ArrayLike, T_cam_target: ArrayLike, setup: Setup, accuracy: AccuracyTargets
) -> CalibrationResult:
    """The calibration with the camera's scale solved (module docstring). *solve* is the solver with
    the camera's translations times a scale; *setup* the set-up whose screw invariant gives the
    start (either does)."""
    data = validate_samples(T_base_tcp, T_cam_target, camera_unit_known=False)
    unit = estimate_unit_scale(setup, data.T_base_tcp, data.T_cam_target, signed=True)
    if unit is None:
        return _unobservable(kind, "the motions' rotations and translations do not show it")
    k0, k0_sd = unit
    if k0 <= 0.0:
        return _unobservable(kind, f"the camera moves mirrored to the robot (scale {k0:.3g})")
    res0, sf0 = solve(k0)
    if sf0 is None or not res0.usable:
        res0.reasons.insert(0, f"camera translations scaled by {k0:.6g} (the screw invariant's start)")
        return res0
    bound = float(min(1.0, max(0.1, 6.0 * k0_sd / k0)))
    u, sigma_u = _profile(sf0, bound)
    k = k0 * float(np.exp(u))
    res, sf = solve(k)
    if sf is None or not res.usable:
        res.reasons.insert(0, f"camera translations scaled by {k:.6g} (profiled)")
        return res
    if np.isfinite(sigma_u) and res.covariance is not None:
        res.covariance = res.covariance + _scale_share(sf, sigma_u)
        res.metrics.update(std_metrics(res.covariance))
        over = (
            res.metrics["std_x_trans_m"] > accuracy.max_std_trans_m
            or res.metrics["std_x_rot_rad"] > accuracy.max_std_rot_rad
        )
        if over and res.verdict == "ok":
            res.verdict = "warning"
            res.reasons.append("with the scale's uncertainty, X's exceeds the accuracy target")
    k_sd = k * sigma_u
    res.estimate["camera_scale"] = k
    res.metrics["camera_scale"] = k
    res.metrics["camera_scale_sd"] = k_sd
    res.reasons.insert(
        0,
        f"camera scale solved: metres = {k:.6g} (+-{k_sd:.2g}, 1 sigma) x camera units; the "
        "uncertainty of X includes the scale's",
    )
    return res
