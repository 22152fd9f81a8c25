"""Kinematic (geometric) calibration of a serial robot from external measurements of its tool.

Method (seed 003, made complete): the robot is parameterised in standard DH, modified DH or POE
(:mod:`plugins.robot.conventions`; every geometric quantity is a named chain parameter), together with
the unknown measurement frame (the robot base in the tracker/camera frame, 6 parameters) and the
measured tool point in the flange frame (3 parameters; 6 with orientation data). The analytic
Jacobian is the screw Jacobian of the chain (seed 003's formulas 14.14-14.18 generalised: each
parameter is a "virtual joint"). Steps:

1. initial measurement frame by a rigid fit (``Rotation.align_vectors``) of the nominal predictions
   to the measurements;
2. identifiability analysis at the initial estimate (:mod:`.identifiability`): redundant parameters
   are fixed, confounded combinations named, and the data's rank compared with the structural rank
   of the parameterisation (a rich random pose set) to detect poses that do not excite the model;
3. Levenberg-Marquardt with step limiting (:mod:`.lm`) on the whitened residuals (position noise
   ``noise_position_m`` per axis; orientation noise ``noise_rotation_rad``);
4. covariance ``s^2 (J^T J)^-1`` of the identified parameters (``s^2`` the a-posteriori variance
   factor unless ``trust_noise``), per-sample residuals, outlier flags (chi-square 99.99 %), a
   before/after table on held-out poses, an optional convergence plot, and a verdict.

The returned :class:`CalibrationResult` holds the calibrated model as a model-file mapping in
``estimate["model_file"]`` (``plugins.robot.model_file.robot_model_from_dict`` rebuilds it) and the
measurement frame as ``estimate["T_meas_base"]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from plugins.calibration.kinematics.data import KinematicSamples
from plugins.calibration.kinematics.frames import _analysis_model, initial_frames
from plugins.calibration.kinematics.identifiability import Identifiability, analyse
from plugins.calibration.kinematics.lm import LMResult, levenberg_marquardt
from plugins.calibration.kinematics.points import ToolPoints, first_point, fit_point_offsets
from plugins.calibration.kinematics.problem import (
    KinematicCalibrationConfig,
    ResidualProblem,
    candidate_parameters,
    error_rows,
    expected_holdout_rms,
    random_configs,
)
from plugins.calibration.result import CalibrationResult, Verdict
from plugins.robot.kinematics import RobotModel
from plugins.robot.model_file import model_to_dict

F64 = NDArray[np.float64]


@dataclass
class KinematicCalibration:
    """Everything a calibration produced; ``result`` is the common :class:`CalibrationResult`."""

    result: CalibrationResult
    model: RobotModel  # calibrated
    initial_model: RobotModel  # nominal geometry + initial measurement frame
    identifiability: Identifiability
    structural: Identifiability
    lm: LMResult
    table: list[dict] = field(default_factory=list)  # before/after rows (mm, deg)
    points: ToolPoints | None = None  # several measured points: their offsets (the model's tool is the first)


# --------------------------------------------------------------------------- steps of calibrate_kinematics


def _prepare_samples(
    model: RobotModel, samples: KinematicSamples, holdout: KinematicSamples | None, cfg: KinematicCalibrationConfig
) -> tuple[list[str], KinematicSamples, KinematicSamples | None]:
    """Input checks and the held-out split: (the samples' warnings, calibration samples, held-out samples).

    Raises ValueError for wrong joint counts, non-positive noise levels and positions spread far
    beyond the robot's reach (millimetres given as metres). Without given held-out samples, a random
    ``cfg.holdout_fraction`` of 8 or more samples is held out (seeded by ``cfg.rng_seed``).
    """
    if samples.n_joints != model.dof:
        raise ValueError(f"samples have {samples.n_joints} joints, model {model.name!r} has {model.dof}")
    if holdout is not None and holdout.n_joints != model.dof:
        raise ValueError(f"held-out samples have {holdout.n_joints} joints, model has {model.dof}")
    if not (cfg.noise_position_m > 0 and cfg.noise_rotation_rad > 0):
        raise ValueError("noise levels must be positive")
    reasons = samples.check()
    if holdout is None and cfg.holdout_fraction > 0 and samples.n_samples >= 8:
        perm = np.random.default_rng(cfg.rng_seed).permutation(samples.n_samples)
        n_hold = max(1, round(cfg.holdout_fraction * samples.n_samples))
        holdout, samples = samples.subset(np.sort(perm[:n_hold])), samples.subset(np.sort(perm[n_hold:]))
    spread = float(np.ptp(samples.positions, axis=0).max())
    reach = model.chain.reach_bound(skip_groups=("base",))
    if spread > 20.0 * reach:
        raise ValueError(
            f"measured positions spread over {spread:.1f} m but {model.name} reaches {reach:.2f} m: "
            "they look like millimetres given as metres"
        )
    return reasons, samples, holdout


@dataclass
class _Start:
    """The initial estimate (step 1) and the candidate parameters."""

    conv: str  # the parameterisation
    model: RobotModel  # nominal geometry + initial measurement frame and tool
    points: ToolPoints | None  # several measured points: their initial offsets
    names: list[str]  # candidate parameters in priority order


def _initial_estimate(model: RobotModel, samples: KinematicSamples, cfg: KinematicCalibrationConfig) -> _Start:
    """Step 1: the model in the chosen parameterisation with the initial measurement frame and tool
    (several points: fitted to the first point's rows, then each other point's offset), and the
    candidate parameters, several points' offsets right after the tool."""
    conv = cfg.parameterisation or model.convention
    work = model.to_convention(conv)
    points = ToolPoints.of(samples)
    if points is None:
        work = initial_frames(work, samples, cfg.estimate_base, cfg.estimate_tool)
    else:  # frame and the first point from the first point's rows, then each other point's offset
        if samples.full_pose or not cfg.estimate_tool:
            raise ValueError("several measured points (a point column) need position data and the tool estimated")
        work = initial_frames(work, first_point(samples, points), cfg.estimate_base, True)
        points = fit_point_offsets(work, samples, points)
    names = candidate_parameters(work, samples.full_pose, cfg)
    if points is not None:  # right after the tool: a point offset is kept before a joint parameter
        at_tool = max(i for i, n in enumerate(names) if n.startswith("tool.")) + 1
        names = names[:at_tool] + points.param_names() + names[at_tool:]
    return _Start(conv, work, points, names)


@dataclass
class _Solution:
    """What :func:`_identify_and_solve` found."""

    model: RobotModel  # calibrated
    points: ToolPoints | None  # the measured points' calibrated offsets
    ident: Identifiability  # of the data, at ``at``
    kept: list[str]  # the identified parameters
    lm: LMResult  # the iterations of all solves, numbered consecutively
    at: RobotModel  # where the identifiability was last analysed


def _identify_and_solve(start: _Start, samples: KinematicSamples, cfg: KinematicCalibrationConfig) -> _Solution:
    """Steps 2 and 3: identifiability analysis, then Levenberg-Marquardt on the kept parameters.

    Identifiability is analysed at the nominal joint geometry, where structural redundancies are
    exact (at calibrated values they become near-redundancies that only slow the solver down).
    A nominal tool point on the last joint axis hides that axis, so after solving, the analysis is
    repeated with the estimated tool point until the identifiable set is stable.
    """
    initial, points, names = start.model, start.points, start.names
    work = initial
    history: list[dict] = []
    kept: list[str] = []
    lm: LMResult | None = None
    at = initial
    for _ in range(3):
        J_at = ResidualProblem(at, samples, names, cfg, points)(np.zeros(len(names)))[1]
        ident = analyse(J_at, names, cfg.identifiability_tol)
        if lm is not None and ident.kept == kept:
            break
        kept = ident.kept
        step_problem = ResidualProblem(work, samples, kept, cfg, points)
        lm = levenberg_marquardt(
            step_problem,
            np.zeros(len(kept)),
            max_iterations=cfg.max_iterations,
            max_step=cfg.max_step_m / cfg.noise_position_m,
        )
        offset = len(history) - 1 if history else 0
        history += [h | {"iteration": h["iteration"] + offset} for h in lm.history[(1 if history else 0) :]]
        work = work.with_values(step_problem.values(lm.x))
        points = step_problem.points_at(lm.x)
        if not lm.converged:
            break
        at = _analysis_model(initial, work, samples.q)
    assert lm is not None
    lm.history = history
    lm.iterations = history[-1]["iteration"]
    return _Solution(work, points, ident, kept, lm, at)


def _structural_identifiability(
    sol: _Solution, samples: KinematicSamples, names: list[str], cfg: KinematicCalibrationConfig
) -> Identifiability:
    """Identifiability of the parameterisation itself: the analysis on a rich random pose set."""
    at, points = sol.at, sol.points
    q_rich = random_configs(at, cfg.structural_poses, cfg.rng_seed + 1)
    T_rich = at.fk(q_rich)
    labels = None if points is None else np.array(points.names)[np.arange(len(q_rich)) % len(points.names)]
    rich = KinematicSamples(q_rich, T_rich[:, :3, 3], T_rich[:, :3, :3] if samples.full_pose else None, point=labels)
    return analyse(
        ResidualProblem(at, rich, names, cfg, points)(np.zeros(len(names)))[1], names, cfg.identifiability_tol
    )


@dataclass
class _FitStatistics:
    """Residual statistics at the solution."""

    n_residuals: int  # whitened residuals
    dof: int
    s2: float  # variance factor (1 with ``trust_noise``)
    cov: F64 | None  # None: singular normal matrix
    residuals: F64  # per sample, m (and rad)
    residual_names: list[str]
    outliers: NDArray[np.bool_]
    chi2_stat: float
    consistent: bool  # chi-square within its 99.9 % bound
    rms_cal_mm: float


def _fit_statistics(problem: ResidualProblem, cfg: KinematicCalibrationConfig) -> _FitStatistics:
    """Step 4's numbers for the kept parameters' *problem*: covariance ``s^2 (J^T J)^-1``,
    per-sample residuals, outlier flags (chi-square 99.99 %), chi-square consistency, RMS."""
    n_kept = len(problem.names)
    r, J = problem(np.zeros(n_kept))
    dof = max(1, r.size - n_kept)
    s2 = 1.0 if cfg.trust_noise else float(r @ r) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)  # J is whitened, so this is in SI units
    except np.linalg.LinAlgError:
        cov = None
    rp, rr = problem.residuals(np.zeros(n_kept))
    residuals = rp if rr is None else np.concatenate([rp, rr], axis=1)
    names_res = ["x", "y", "z"] + (["rx", "ry", "rz"] if rr is not None else [])
    d2 = np.sum((rp / cfg.noise_position_m) ** 2, axis=1) / s2
    outliers = d2 > chi2.ppf(0.9999, 3)
    chi2_stat = float(r @ r)
    consistent = chi2_stat <= chi2.ppf(0.999, dof)
    rms_cal_mm = float(np.sqrt(np.mean(np.sum(rp**2, axis=1)))) * 1e3
    return _FitStatistics(r.size, dof, s2, cov, residuals, names_res, outliers, chi2_stat, consistent, rms_cal_mm)


def _implausible_offsets(start: _Start, sol: _Solution, cfg: KinematicCalibrationConfig) -> list[str]:
    """Joint parameters that moved beyond ``cfg.plausible_offset_m`` / ``_rad``, as text."""
    calibrated, initial, chain = sol.model, start.model, sol.model.chain
    implausible = []
    for n in sol.kept:
        if not n.startswith("joint"):
            continue
        i = chain.index(n)
        d = float(calibrated.param_values[i] - initial.param_values[i])
        limit = cfg.plausible_offset_m if chain.param_kind(n) == "length" else cfg.plausible_offset_rad
        if abs(d) > limit:
            implausible.append(
                f"{n} {d * 1e3:+.1f} mm" if chain.param_kind(n) == "length" else f"{n} {np.degrees(d):+.2f} deg"
            )
    return implausible


def _verdict(
    sol: _Solution,
    structural: Identifiability,
    stats: _FitStatistics,
    implausible: list[str],
    cfg: KinematicCalibrationConfig,
    reasons: list[str],
    advice: list[str],
) -> Verdict:
    """The verdict: ``failed`` (no convergence, huge residuals) over ``degenerate`` (parameters the
    poses do not excite, too few residuals, singular normal matrix) over ``warning`` (outliers,
    inconsistent residuals, implausible offsets). Appends reasons and advice in the checks' order."""
    verdict: Verdict = "ok"
    kept = sol.kept
    if sol.ident.dropped:
        reasons.append(
            f"{len(sol.ident.dropped)} of {len(sol.ident.names)} parameters not identifiable, fixed at nominal: "
            + "; ".join(sol.ident.describe_dropped())
        )
    missing = [n for n in structural.kept if n not in kept]
    if missing:
        verdict = "degenerate"
        reasons.append(f"the poses do not excite {', '.join(missing)} (identifiable with other poses)")
        advice.append("add poses that move the joints named above over a wide range (tens of degrees)")
    if stats.n_residuals <= len(kept):
        verdict = "degenerate"
        reasons.append(f"{stats.n_residuals} residuals for {len(kept)} unknowns: add poses")
    if stats.cov is None:
        verdict = "degenerate"
        reasons.append("normal matrix singular at the solution")
    if not sol.lm.converged:
        verdict = "failed"
        reasons.append(f"Levenberg-Marquardt: {sol.lm.message}")
    if stats.rms_cal_mm > 100.0:
        verdict = "failed"
        reasons.append(f"residual RMS {stats.rms_cal_mm:.1f} mm after calibration: wrong model, joint order or units")
    if implausible:
        reasons.append(
            "joint parameters moved far beyond manufacturing tolerances: "
            + ", ".join(implausible)
            + " (wrong robot model, joint order or joint sign?)"
        )
        advice.append("check that the model and the joint angle convention match the robot that was measured")
    if verdict == "ok" and (np.any(stats.outliers) or not stats.consistent or implausible):
        verdict = "warning"
    if np.any(stats.outliers):
        reasons.append(f"{int(stats.outliers.sum())} outlier samples (residual beyond the 99.99 % chi-square bound)")
    if not stats.consistent:
        reasons.append(
            f"residuals ({np.sqrt(stats.chi2_stat / stats.dof) * cfg.noise_position_m * 1e3:.3f} mm per axis, "
            f"with dof = residuals - parameters) "
            f"exceed the stated noise ({cfg.noise_position_m * 1e3:.3f} mm): unmodelled effects remain "
            "(see vgr gap)"
        )
    return verdict


def _table_and_metrics(
    start: _Start,
    sol: _Solution,
    stats: _FitStatistics,
    cfg: KinematicCalibrationConfig,
    samples: KinematicSamples,
    holdout: KinematicSamples | None,
) -> tuple[list[dict[str, Any]], dict[str, float]]:
    """The before/after table (mm, deg) of the calibration and held-out samples and the metrics;
    with held-out samples and a covariance also the held-out RMS a correct model would give
    (:func:`expected_holdout_rms`, in the metrics and the table's held-out row)."""
    table: list[dict[str, Any]] = []
    for label, data in (("calibration", samples), ("held-out", holdout)):
        if data is None:
            continue
        before, after = error_rows(start.model, data, start.points), error_rows(sol.model, data, sol.points)
        table.append({"set": label, "n": data.n_samples, "before": before, "after": after})
    metrics = {
        "rms_before_mm": table[0]["before"]["rms_mm"],
        "rms_after_mm": table[0]["after"]["rms_mm"],
        "observability_o1": sol.ident.observability_o1,
        "condition_number": sol.ident.condition_number,
        "n_params_identified": float(len(sol.kept)),
        "n_params_dropped": float(len(sol.ident.dropped)),
        "sigma_position_mm": float(np.sqrt(stats.s2)) * cfg.noise_position_m * 1e3,
        "chi2": stats.chi2_stat,
        "chi2_dof": float(stats.dof),
    }
    if not cfg.trust_noise:
        metrics["covariance_dof"] = float(stats.dof)  # s^2 estimated: confidence regions use F(k, dof)
    if len(table) > 1:
        metrics["holdout_rms_before_mm"] = table[1]["before"]["rms_mm"]
        metrics["holdout_rms_after_mm"] = table[1]["after"]["rms_mm"]
        if stats.cov is not None and holdout is not None:
            sigma = np.sqrt(stats.s2) * cfg.noise_position_m
            expected, h_dof = expected_holdout_rms(sol.model, holdout, sol.kept, stats.cov, sigma, sol.points)
            metrics["holdout_rms_expected_mm"] = expected * 1e3
            metrics["holdout_rms_dof"] = h_dof
            table[1]["expected_rms_mm"] = expected * 1e3
    return table, metrics


def _estimate(start: _Start, sol: _Solution) -> dict[str, Any]:
    """The result's ``estimate``: measurement frame, tool, the kept parameters' offsets from their
    initial values, the calibrated model file and (several points) every point on the flange."""
    calibrated, initial, points, initial_points, kept = sol.model, start.model, sol.points, start.points, sol.kept
    values = calibrated.param_values
    moved = {n: float(values[calibrated.chain.index(n)] - initial.param_values[calibrated.chain.index(n)])
             for n in kept if n in calibrated.param_names}  # fmt: skip
    if points is not None and initial_points is not None:  # a point's offset from the first point moved too
        moved |= dict(zip(points.param_names(), (points.flat() - initial_points.flat()).tolist(), strict=True))
    estimate = {
        "T_meas_base": calibrated.T_world_base,
        "T_flange_tcp": calibrated.T_flange_tcp,
        "offsets": {n: moved[n] for n in kept},
        "model_file": model_to_dict(calibrated),
    }
    if points is not None:  # every measured point on the flange (the model's own tool is the first)
        estimate["tool_points"] = points.flange_points(calibrated)
        estimate["tool_point_offsets"] = points.as_dict()  # what ToolPoints.of(samples, known) rebuilds
    return estimate


# --------------------------------------------------------------------------- main entry point


def calibrate_kinematics(
    model: RobotModel,
    samples: KinematicSamples,
    *,
    holdout: KinematicSamples | None = None,
    config: KinematicCalibrationConfig | None = None,
) -> KinematicCalibration:
    """Calibrate ``model``'s geometry, measurement frame and tool from ``samples``.

    Raises ValueError for malformed input (wrong number of joints, NaN, bad rotations); a calibration
    that cannot be trusted comes back with verdict ``degenerate`` or ``failed`` and reasons.
    """
    cfg = config or KinematicCalibrationConfig()
    reasons, samples, holdout = _prepare_samples(model, samples, holdout, cfg)
    advice: list[str] = []
    start = _initial_estimate(model, samples, cfg)
    sol = _identify_and_solve(start, samples, cfg)
    structural = _structural_identifiability(sol, samples, start.names, cfg)
    stats = _fit_statistics(ResidualProblem(sol.model, samples, sol.kept, cfg, sol.points), cfg)
    verdict = _verdict(sol, structural, stats, _implausible_offsets(start, sol, cfg), cfg, reasons, advice)
    table, metrics = _table_and_metrics(start, sol, stats, cfg, samples, holdout)
    result = CalibrationResult(
        kind="kinematic",
        verdict=verdict,
        estimate=_estimate(start, sol),
        param_names=sol.kept,
        covariance=stats.cov,
        residuals=stats.residuals,
        residual_names=stats.residual_names,
        outliers=stats.outliers,
        reasons=reasons,
        advice=advice,
        metrics=metrics,
        method=f"levenberg-marquardt, {start.conv} parameters, {'pose' if samples.full_pose else 'position'} data",
        iterations=sol.lm.iterations,
    )
    return KinematicCalibration(result, sol.model, start.model, sol.ident, structural, sol.lm, table, sol.points)
