"""Vive desk calibration (seed 001): T_base_desktop and T_tracker_tcp from fixture contacts.

Pipeline of :func:`calibrate_vive_desk`:

1. input checks (units, duplicates, >= 3 distinct points, spacing) and seed 001's pose-consistency
   bands;
2. initial estimate (:mod:`.initial`: seed step 1 made exact, or the literal seed step 1);
3. maximum-likelihood refinement on SE(3) (:mod:`.model`): scipy ``least_squares`` (Levenberg-
   Marquardt) with the exact Jacobian, residuals whitened by the noise model, the fixture scatter of
   every contact estimated as a nuisance rotation with its prior;
   A design whose null space contains the lever arm (one fixture orientation) gets a weak prior on
   it (``lever_arm_prior_sigma_m``); other undetermined directions are gauge-fixed at the start;
4. covariance of the 12 unknowns (marginal over the nuisance), chi-square consistency, studentised
   per-contact outlier tests, structural identifiability (the design's null space, e.g. the lever-arm
   / desk-origin trade-off of a single fixture orientation) and the predicted accuracy;
5. seed 001's step-3 errors and acceptance test (mean position < 1 mm, mean rotation < 0.5 deg).

The verdict is the worst finding; ``reasons`` and ``advice`` say what to do.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import null_space
from scipy.optimize import least_squares

from engine.transforms import as_transform, exp_so3
from plugins.calibration.pose_lsq import (
    Identifiability,
    Issue,
    analyse_identifiability,
    chi2_consistency,
    marginal_covariance,
    result_from_issues,
    robust_block_pvalues,
    studentised_block_tests,
)
from plugins.calibration.result import CalibrationResult
from plugins.calibration.vive_desk.checks import (
    ViveThresholds,
    check_samples,
    check_units,
    collinearity_issue,
    orientation_groups,
    pose_consistency,
)
from plugins.calibration.vive_desk.data import TrackerTcpPrior, ViveDeskData
from plugins.calibration.vive_desk.initial import initial_estimate, seed_step1_T_base_desktop
from plugins.calibration.vive_desk.model import N_MAIN, PARAM_NAMES, DeskProblem, seed_style_errors
from plugins.calibration.vive_desk.realtime import desktop_tcp_jacobians

F64 = NDArray[np.float64]

RESIDUAL_NAMES = [
    "tcp_position_error_base.x",
    "tcp_position_error_base.y",
    "tcp_position_error_base.z",
    "tcp_rotation_error.x",
    "tcp_rotation_error.y",
    "tcp_rotation_error.z",
]
METHOD = (
    "exact closed-form init (seed 001 step 1 via Kabsch) + maximum likelihood on SE(3): "
    "scipy least_squares LM, analytic Jacobian, fixture scatter marginalised as nuisance"
)


def _solve(problem: DeskProblem, max_nfev: int) -> tuple[DeskProblem, F64, int, bool, str]:
    """Two LM passes (the second re-linearised at the first's optimum). Returns the re-centred
    problem, x, evaluations, success and the optimiser message."""
    x = np.zeros(problem.n_params)
    nfev = 0
    ok = True
    msg = ""
    for _ in range(2):
        fit = least_squares(
            problem.residual,
            x,
            jac=problem.jacobian,
            method="lm",
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=max_nfev,
        )
        nfev += int(fit.nfev)
        ok = bool(fit.success)
        msg = str(fit.message)
        problem, x = problem.recentred(fit.x)
    return problem, x, nfev, ok, msg


_SCALES = np.full(N_MAIN, 1e-3)  # 1 mm / 1 mrad: the units the identifiability analysis compares


def _identifiability(problem: DeskProblem, x: F64) -> Identifiability:
    """Structural identifiability of the design of *problem* at *x*."""
    J_main, J_nuis = problem.design_jacobians(x)
    return analyse_identifiability(J_main, PARAM_NAMES, _SCALES, J_nuisance=J_nuis)


_PRIOR_ADVICE = (
    "the lever arm from CAD / caliper as a prior (TCP position in the tracker frame; command line: "
    "--tcp-prior-mm X Y Z [--tcp-prior-sigma-mm 1], Python: prior=TrackerTcpPrior(T_tracker_tcp, sigma_m))"
)


def _describe_null_space(ident: Identifiability, n_groups: int) -> Issue:
    """Degenerate-design issue in words, with advice on the measurements that fix it."""
    k = ident.n_params - ident.rank
    trans_only = all(np.allclose(v[[3, 4, 5, 9, 10, 11]], 0, atol=1e-3) for v in ident.null_space)
    if not trans_only:
        return Issue(
            "degenerate",
            f"{k} parameter combination(s) not identifiable: [{'; '.join(ident.descriptions)}]",
            "add contact points off the line of the existing ones and more fixture orientations",
        )
    if k == 1:
        d = ident.null_space[0][6:9]
        d = d / np.linalg.norm(d)
        what = (
            "the lever-arm component along the single tilt axis (tracker frame direction "
            f"[{d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f}])"
        )
        advice = (
            "add contacts with the fixture tilted about a different axis of the desk (>= 30 deg), or " + _PRIOR_ADVICE
        )
    else:
        what = f"{k} components of the tracker-to-TCP lever arm"
        advice = (
            f"{'one fixture orientation' if n_groups <= 1 else 'these fixture orientations'} cannot "
            "determine the tracker-to-TCP lever arm; add ONE of: (a) contacts at two more fixture "
            "orientations tilted about two different axes (e.g. the same points with the fixture "
            "tilted 30 deg about desk x, then 30 deg about desk y; free-orientation pivot contacts also "
            "work), or (b) " + _PRIOR_ADVICE
        )
    return Issue(
        "degenerate",
        f"{what} not identifiable: moving T_tracker_tcp's origin by d and the desk origin by "
        "R_base_tracker d explains the contacts equally well when the tool is not turned between "
        "contacts; T_desktop_tcp is then only right at the calibration orientation (error about "
        "turn angle x lever-arm error elsewhere)",
        advice,
    )


def cramer_rao_bound(
    data: ViveDeskData, T_base_desktop: F64, T_tracker_tcp: F64, prior: TrackerTcpPrior | None = None
) -> tuple[F64, int]:
    """(12x12 Cramér–Rao bound of the 12 unknowns at the given truth, rank of the information).

    Evaluated with the data's design (points, fixture orientations, noise model) and noise-free
    measurements; the fixture scatter is marginalised. A rank below 12 + nuisance means some
    combinations have no finite bound (the pseudo-inverse then bounds the estimable ones only).
    """
    problem = DeskProblem(data, np.asarray(T_base_desktop, float), np.asarray(T_tracker_tcp, float),
                          data.R_desktop_tcp, prior)  # fmt: skip
    _, J = problem.residual_and_jacobian(np.zeros(problem.n_params), structural=True)
    return marginal_covariance(J, N_MAIN)


def _check_input(
    data: ViveDeskData, prior: TrackerTcpPrior | None, th: ViveThresholds
) -> tuple[list[Issue], dict[str, float]]:
    """Step 1: reject unusable input (the prior, units, the samples: ValueError) and collect the
    findings and metrics of the sample checks and of seed 001's pose-consistency bands."""
    if prior is not None:
        as_transform(prior.T_tracker_tcp, name="prior T_tracker_tcp")
        if not prior.sigma_position_m > 0:
            raise ValueError("prior sigma_position_m must be > 0")
    issues: list[Issue] = [Issue("info", n) for n in data.notes]
    check_units(data)
    sample_issues, metrics = check_samples(data, th)
    issues += sample_issues
    cons_issues, cons_metrics = pose_consistency(data, th)
    issues += cons_issues
    metrics.update(cons_metrics)
    return issues, metrics


def _initial_problem(
    data: ViveDeskData,
    prior: TrackerTcpPrior | None,
    init: Literal["exact", "seed"],
    lever_arm_prior_sigma_m: float | None,
) -> DeskProblem:
    """Step 2: the initial estimate and the problem around it: free samples' fixture reference
    orientations follow from the initial poses; a design that cannot determine everything is
    regularised or gauge-fixed (:func:`_regularise_design`)."""
    if init == "seed":
        T_BD0 = seed_step1_T_base_desktop(data.T_base_tracker)
        T_KC0 = np.eye(4) if prior is None else prior.T_tracker_tcp.copy()
    else:
        T_BD0, T_KC0 = initial_estimate(data, prior)
    R_ref = data.R_desktop_tcp.copy()
    for i in np.flatnonzero(~data.orientation_known):
        R_ref[i] = T_BD0[:3, :3].T @ data.T_base_tracker[i, :3, :3] @ T_KC0[:3, :3]
    problem = DeskProblem(data, T_BD0, T_KC0, R_ref, prior)
    _regularise_design(problem, T_KC0, prior, lever_arm_prior_sigma_m)
    return problem


def _regularise_design(
    problem: DeskProblem, T_KC0: F64, prior: TrackerTcpPrior | None, lever_arm_prior_sigma_m: float | None
) -> None:
    """Set *problem*'s lever-arm prior and gauge for a design that cannot determine everything.

    A design that cannot determine the lever arm (one fixture orientation) gets a weak prior on it
    (the tracker sits within ~lever_arm_prior_sigma_m of the TCP): the fixture scatter then informs
    the lever arm as far as it can, instead of noise driving it metres away. Directions still
    undetermined are gauge-fixed: they stay at the initial estimate.
    """
    ident0 = _identifiability(problem, np.zeros(problem.n_params))
    if not ident0.full_rank and prior is None and lever_arm_prior_sigma_m:
        problem.prior = TrackerTcpPrior(T_KC0.copy(), lever_arm_prior_sigma_m)
        ident0 = _identifiability(problem, np.zeros(problem.n_params))
    if not ident0.full_rank:
        problem.gauge = ident0.null_space * _SCALES / np.linalg.norm(ident0.null_space * _SCALES, axis=1)[:, None]


def _covariance(problem: DeskProblem, J: F64) -> tuple[F64, int]:
    """Covariance of the 12 unknowns (marginal over the nuisance) and the information rank.

    A gauge-fixed design's covariance lives on its identifiable subspace only; the pinned
    directions count towards the rank (they are not free parameters)."""
    if problem.gauge is None:
        return marginal_covariance(J, N_MAIN)
    k = problem.n_gauge
    P = null_space(problem.gauge)  # (12, 12 - k) orthonormal identifiable directions
    Pfull = np.zeros((problem.n_params, problem.n_params - k))
    Pfull[:N_MAIN, : N_MAIN - k] = P
    Pfull[N_MAIN:, N_MAIN - k :] = np.eye(problem.n_params - N_MAIN)
    cov_p, rank = marginal_covariance(J[:-k] @ Pfull, N_MAIN - k)
    cov = P @ cov_p @ P.T
    rank += k
    return cov, rank


def _check_consistency(
    r: F64, rank: int, cov: F64, th: ViveThresholds, metrics: dict[str, float], issues: list[Issue]
) -> tuple[F64, float]:
    """Chi-square consistency of the whitened residuals *r* with the noise model (metrics added).
    A noise model that is too optimistic inflates the covariance and is warned about.
    Returns (the covariance to report, the chi-square p-value)."""
    dof = r.size - rank
    chi2_dof, p_chi2 = chi2_consistency(float(r @ r), dof)
    metrics.update({"chi2_per_dof": chi2_dof, "chi2_p_value": p_chi2, "dof": float(dof)})
    if p_chi2 < th.chi2_p_value:
        cov = cov * chi2_dof
        issues.append(
            Issue(
                "warning",
                f"residuals are {np.sqrt(chi2_dof):.1f}x larger than the noise model predicts "
                f"(chi2/dof = {chi2_dof:.2f}, p = {p_chi2:.1e}); covariance inflated accordingly",
                "check the noise model (tracker jitter, fixture scatter) and re-measure flagged contacts",
            )
        )
    return cov, p_chi2


def _check_design(
    data: ViveDeskData,
    problem: DeskProblem,
    T_BD: F64,
    T_KC: F64,
    prior: TrackerTcpPrior | None,
    th: ViveThresholds,
    metrics: dict[str, float],
    issues: list[Issue],
) -> tuple[Identifiability, list[NDArray[np.int_]]]:
    """Structural identifiability of the design at the solution: collinear contact points and the
    design's null space become issues. Returns (the analysis, the fixture orientation groups)."""
    ident = _identifiability(DeskProblem(data, T_BD, T_KC, problem.R_fix_ref, prior), np.zeros(problem.n_params))
    metrics["design_rank"] = float(ident.rank)
    groups = orientation_groups(data)
    col = collinearity_issue(metrics["point_line_width_mm"] * 1e-3, not ident.full_rank, th)
    if col is not None:
        issues.append(col)
    if not ident.full_rank:
        issues.append(_describe_null_space(ident, len(groups)))
    return ident, groups


def _predicted_accuracy(
    data: ViveDeskData, groups: list[NDArray[np.int_]], T_BD: F64, T_KC: F64, cov: F64
) -> dict[str, float]:
    """Predicted accuracy (1-sigma RMS, m / rad) of each block, and of the TCP pose in the desk
    frame at the (first) calibration orientation: what users see."""
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    pred = {
        "T_base_desktop_position": float(np.sqrt(np.sum(sd[0:3] ** 2))),
        "T_base_desktop_rotation": float(np.sqrt(np.sum(sd[3:6] ** 2))),
        "T_tracker_tcp_position": float(np.sqrt(np.sum(sd[6:9] ** 2))),
        "T_tracker_tcp_rotation": float(np.sqrt(np.sum(sd[9:12] ** 2))),
    }
    T_ref_tracker = data.T_base_tracker[groups[0][0] if groups else 0]
    Jc, _ = desktop_tcp_jacobians(T_ref_tracker, T_BD, T_KC)
    cov_out = Jc @ cov @ Jc.T
    pred["T_desktop_tcp_at_calibration_position"] = float(np.sqrt(np.trace(cov_out[:3, :3])))
    pred["T_desktop_tcp_at_calibration_rotation"] = float(np.sqrt(np.trace(cov_out[3:, 3:])))
    return pred


def _check_accuracy(
    pred: dict[str, float], full_rank: bool, th: ViveThresholds, metrics: dict[str, float], issues: list[Issue]
) -> None:
    """Record the predicted accuracy (mm / deg metrics) and, for a full-rank design, warn about
    blocks determined worse than the thresholds."""
    for k, v in pred.items():
        unit, scale = ("mm", 1e3) if k.endswith("position") else ("deg", np.degrees(1.0))
        metrics[f"predicted_rms_{k}_{unit}"] = float(v * scale)
    if not full_rank:
        return
    weak = []
    for blk in ("T_base_desktop", "T_tracker_tcp"):
        if pred[f"{blk}_position"] > th.max_predicted_position_rms_m:
            weak.append(f"{blk} position {pred[f'{blk}_position'] * 1e3:.2f} mm")
        if np.degrees(pred[f"{blk}_rotation"]) > th.max_predicted_rotation_rms_deg:
            weak.append(f"{blk} rotation {np.degrees(pred[f'{blk}_rotation']):.3f} deg")
    if weak:
        issues.append(
            Issue(
                "warning",
                "weakly determined (predicted RMS error): " + ", ".join(weak),
                "add contacts: more points spread over the desk and larger tilts between fixture "
                "orientations (>= 30 deg)",
            )
        )


def _check_outliers(
    data: ViveDeskData,
    problem: DeskProblem,
    J: F64,
    r: F64,
    p_chi2: float,
    th: ViveThresholds,
    metrics: dict[str, float],
    issues: list[Issue],
) -> NDArray[np.bool_]:
    """Studentised per-contact outlier tests (against the data's own scale when the noise model is
    too optimistic, *p_chi2* below the threshold). Returns the outlier flags."""
    blocks = problem.sample_row_blocks()
    stats, dofs, pvals = studentised_block_tests(J, r, blocks)
    if p_chi2 < th.chi2_p_value:  # noise model too optimistic: test against the data's own scale
        pvals, factor = robust_block_pvalues(stats, dofs)
        metrics["robust_variance_factor"] = factor
    outliers = (pvals < th.outlier_p_value) & (dofs > 0)
    metrics["n_untestable_samples"] = float(np.count_nonzero(dofs == 0))
    if outliers.any():
        bad = [data.labels[i] for i in np.flatnonzero(outliers)]
        issues.append(
            Issue(
                "warning",
                f"contact(s) {', '.join(bad)} disagree with the others beyond the noise model "
                f"(studentised test p < {th.outlier_p_value:g})",
                f"re-measure contact(s) {', '.join(bad)} (fixture seated? right desk point?)",
            )
        )
    return outliers


def _seed_errors(data: ViveDeskData, problem: DeskProblem, x: F64, T_BD: F64, T_KC: F64) -> tuple[F64, F64]:
    """Seed 001 step 3's per-contact errors at the solution, free samples at their estimated
    fixture orientation. Returns (the fixture scatter rotation vectors, the (N, 6) errors)."""
    zeta = problem.zetas(x)
    R_eff = data.R_desktop_tcp.copy()
    for i in np.flatnonzero(~data.orientation_known):
        R_eff[i] = problem.R_fix_ref[i] @ exp_so3(zeta[i])
    return zeta, seed_style_errors(data, T_BD, T_KC, R_eff)


def _check_seed_acceptance(
    data: ViveDeskData, errs: F64, nfev: int, th: ViveThresholds, metrics: dict[str, float], issues: list[Issue]
) -> None:
    """Seed 001's acceptance test on the step-3 errors *errs* (mean position < 1 mm, mean rotation
    < 0.5 deg by default); records the error metrics and the optimiser's evaluation count."""
    pos_err = np.linalg.norm(errs[:, :3], axis=1)
    rot_err = np.degrees(np.linalg.norm(errs[:, 3:], axis=1))
    known = data.orientation_known
    mean_rot = float(rot_err[known].mean()) if known.any() else 0.0
    metrics.update(
        {
            "mean_position_error_mm": float(pos_err.mean() * 1e3),
            "max_position_error_mm": float(pos_err.max() * 1e3),
            "mean_rotation_error_deg": mean_rot,
            "max_rotation_error_deg": float(rot_err[known].max()) if known.any() else 0.0,
            "function_evaluations": float(nfev),
        }
    )
    seed_ok = (
        metrics["mean_position_error_mm"] < th.accept_mean_position_m * 1e3 and mean_rot < th.accept_mean_rotation_deg
    )
    if seed_ok:
        issues.append(
            Issue(
                "info",
                "Vive desk acceptance passed (mean position < 1 mm, mean rotation < 0.5 deg; docs/vive_and_tcp.md)",
            )
        )
    else:
        issues.append(
            Issue(
                "failed",
                "Vive desk acceptance not met (docs/vive_and_tcp.md): mean position error "
                f"{metrics['mean_position_error_mm']:.2f} mm "
                f"(limit {th.accept_mean_position_m * 1e3:.1f}), mean rotation error {mean_rot:.2f} deg "
                f"(limit {th.accept_mean_rotation_deg})",
                "check that the fixture seats the tool the same way every time, the desk point "
                "coordinates and contact_offset_z; re-measure flagged contacts",
            )
        )


def _estimate(data: ViveDeskData, T_BD: F64, T_KC: F64, zeta: F64) -> dict[str, Any]:
    """The result's ``estimate`` mapping: the two poses, the fixture scatter, the noise model used."""
    nz = data.noise
    return {
        "T_base_desktop": T_BD,
        "T_tracker_tcp": T_KC,
        "fixture_scatter_rotvec": zeta,
        "noise_model": {
            "tracker_position_sigma_m": nz.tracker_position_sigma_m,
            "tracker_rotation_sigma_rad": nz.tracker_rotation_sigma_rad,
            "fixture_rotation_sigma_rad": nz.fixture_rotation_sigma_rad,
            "desk_point_sigma_m": nz.desk_point_sigma_m,
        },
        "sample_labels": list(data.labels),
    }


def calibrate_vive_desk(
    data: ViveDeskData,
    *,
    prior: TrackerTcpPrior | None = None,
    thresholds: ViveThresholds | None = None,
    init: Literal["exact", "seed"] = "exact",
    lever_arm_prior_sigma_m: float | None = 0.1,
    max_nfev: int = 200,
) -> CalibrationResult:
    """Calibrate T_base_desktop and T_tracker_tcp; see the module docstring.

    ``prior``: knowledge of T_tracker_tcp (CAD, caliper); it makes a single fixture orientation
    usable. ``lever_arm_prior_sigma_m``: without ``prior``, a design that cannot determine the
    lever arm is regularised by ``t_tracker_tcp ~ N(initial, sigma^2 I)`` (the verdict stays
    ``degenerate``); ``None`` gauge-fixes those directions at the initial estimate instead.
    Raises ValueError for unusable input (NaN, non-rotations, < 3 distinct points, mm vs m,
    duplicated rows); quality problems come back in the verdict.
    """
    th = thresholds or ViveThresholds()
    issues, metrics = _check_input(data, prior, th)
    problem = _initial_problem(data, prior, init, lever_arm_prior_sigma_m)
    problem, x, nfev, ok, msg = _solve(problem, max_nfev)
    T_BD, T_KC = problem.poses(x)
    r, J = problem.residual_and_jacobian(x)
    if not ok or not np.all(np.isfinite(r)):
        issues.append(Issue("failed", f"optimiser did not converge: {msg}", "check the input data"))
    cov, rank = _covariance(problem, J)
    cov, p_chi2 = _check_consistency(r, rank, cov, th, metrics, issues)
    ident, groups = _check_design(data, problem, T_BD, T_KC, prior, th, metrics, issues)
    _check_accuracy(_predicted_accuracy(data, groups, T_BD, T_KC, cov), ident.full_rank, th, metrics, issues)
    outliers = _check_outliers(data, problem, J, r, p_chi2, th, metrics, issues)
    zeta, errs = _seed_errors(data, problem, x, T_BD, T_KC)
    _check_seed_acceptance(data, errs, nfev, th, metrics, issues)
    return result_from_issues(
        "vive_desk",
        issues,
        estimate=_estimate(data, T_BD, T_KC, zeta),
        param_names=list(PARAM_NAMES),
        covariance=cov,
        residuals=errs,
        residual_names=list(RESIDUAL_NAMES),
        outliers=outliers,
        metrics=metrics,
        method=METHOD
        if init == "exact"
        else METHOD.replace("exact closed-form init (seed 001 step 1 via Kabsch)", "literal seed 001 step-1 init"),
        iterations=nfev,
    )
