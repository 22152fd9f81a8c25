"""TCP calibration with a fixed camera (seed 002): T_cam_base and the TCP point in the flange frame.

:func:`calibrate_tcp_camera`:

1. input checks (NaN, rotations, >= 4 samples, duplicates, mm vs m by magnitude and by the
   rigid-displacement ratio of pure translations);
2. closed-form start: seed 002's method when pure translations along >= 2 directions exist,
   else the general linear start (:mod:`.initial`);
3. maximum likelihood: scipy ``least_squares`` on ``(T_cam_base (v, w in the camera frame),
   p_flange_tcp)`` with the analytic Jacobian, every sample whitened by its covariance
   ``diag(camera_sigma^2) + R_cam_base (robot position + robot rotation x lever) R_cam_base^T``;
   optional robust loss;
4. covariance (9x9), chi-square consistency, studentised per-sample outlier flags, identifiability
   (rotations about one axis leave the TCP component along it unobservable; collinear TCP positions
   leave the camera rotation about that line unobservable) with advice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import OptimizeResult, least_squares
from scipy.spatial.distance import pdist

from engine.transforms import T_from_Rt, exp_so3, hat, inv, so3_left_jacobian
from plugins.calibration.pose_lsq import (
    Identifiability,
    Issue,
    analyse_identifiability,
    chi2_consistency,
    looks_like_millimetres,
    marginal_covariance,
    result_from_issues,
    robust_block_pvalues,
    studentised_block_tests,
)
from plugins.calibration.result import CalibrationResult
from plugins.calibration.tcp_camera.data import TcpCameraData
from plugins.calibration.tcp_camera.initial import (
    TRANSLATIONS_METHOD,
    ClosedForm,
    general_linear,
    seed002_closed_form,
    translation_groups,
    translation_span,
)

F64 = NDArray[np.float64]

PARAM_NAMES = [f"T_cam_base.{c}" for c in ("vx", "vy", "vz", "wx", "wy", "wz")] + [
    f"p_flange_tcp.{c}" for c in ("x", "y", "z")
]
RESIDUAL_NAMES = ["p_cam_error.x", "p_cam_error.y", "p_cam_error.z"]


@dataclass(frozen=True)
class TcpThresholds:
    """Acceptance thresholds (SI units unless the name says otherwise).

    ``identifiability_rel_tol``: a parameter direction counts as not identifiable when the data
    constrain it less than this fraction of the best-determined one (1e-3 is about 0.06 deg of
    rotation about a second axis, with parameters scaled to mm / mrad).
    """

    pure_translation_tol_deg: float = 0.05
    min_translation_span_m: float = 0.02
    identifiability_rel_tol: float = 1e-3
    max_predicted_tcp_rms_m: float = 1.0e-3
    max_predicted_rotation_rms_deg: float = 0.2
    outlier_p_value: float = 1e-3
    chi2_p_value: float = 1e-3


def _check_input(data: TcpCameraData, groups: list[NDArray[np.int_]]) -> list[Issue]:
    if data.n < 4:
        raise ValueError(f"need at least 4 samples (9 unknowns, 3 equations per sample, plus redundancy), got {data.n}")
    T = data.T_base_flange
    for i in range(data.n):
        for j in range(i):
            if np.allclose(T[i], T[j], atol=1e-9) and np.allclose(data.p_cam[i], data.p_cam[j], atol=1e-9):
                raise ValueError(
                    f"samples {data.labels[j]} and {data.labels[i]} are identical (copied row); remove one"
                )
    t = T[:, :3, 3]
    if looks_like_millimetres(t, 5.0):
        raise ValueError(
            f"flange positions reach {np.max(np.abs(t)):.1f}: robot reach is a few metres, these look "
            "like millimetres; give metres (or 'units': 'mm')"
        )
    if looks_like_millimetres(data.p_cam, 10.0):
        raise ValueError(
            f"camera points reach {np.max(np.abs(data.p_cam)):.1f}: these look like millimetres; give "
            "metres (or 'camera_units': 'mm')"
        )
    # rigid motion preserves lengths: camera displacements must match flange displacements
    ratios = []
    for g in groups:
        dc, dt = pdist(data.p_cam[g]), pdist(t[g])
        ok = dt > 1e-3
        ratios += list(dc[ok] / dt[ok])
    if ratios:
        r = float(np.median(ratios))
        if r > 2.0 or r < 0.5:
            raise ValueError(
                f"mixed units: pure translations moved the TCP {r:.3g}x as far in the camera as the "
                "flange moved (a rigid motion gives 1); one side is probably in mm, the other in m"
            )
    issues = [Issue("info", n) for n in data.notes]
    pc = data.p_cam - data.p_cam.mean(0)
    tc = t - t.mean(0)
    spread_c = float(np.sqrt(np.mean(np.sum(pc**2, 1))))
    spread_t = float(np.sqrt(np.mean(np.sum(tc**2, 1))))
    if spread_t > 1e-3 and not 0.05 < spread_c / spread_t < 20:
        raise ValueError(f"mixed units: camera points spread {spread_c:.4g} but flange positions {spread_t:.4g}")
    return issues


class _Problem:
    """Whitened residuals r_i = L_i^-1 (p_cam_i - p_hat_i) around reference (R0, t0, p0)."""

    def __init__(self, data: TcpCameraData, T_CB0: F64, p0: F64) -> None:
        self.data, self.R0, self.t0, self.p0 = data, T_CB0[:3, :3], T_CB0[:3, 3], p0
        self.Linv = self._whiteners(self.R0, p0)

    def _whiteners(self, R_cb: F64, p: F64) -> F64:
        nz = self.data.noise
        Sc = np.diag(np.square(nz.camera_sigma_m))
        out = np.empty((self.data.n, 3, 3))
        for i in range(self.data.n):
            R = self.data.T_base_flange[i, :3, :3]
            S_rob = nz.robot_position_sigma_m**2 * np.eye(3)
            S_rob = S_rob + nz.robot_rotation_sigma_rad**2 * R @ hat(p) @ hat(p).T @ R.T
            S = Sc + R_cb @ S_rob @ R_cb.T
            out[i] = np.linalg.inv(np.linalg.cholesky(S))
        return out

    def unpack(self, x: F64) -> tuple[F64, F64, F64]:
        return exp_so3(x[3:6]) @ self.R0, self.t0 + x[0:3], self.p0 + x[6:9]

    def residual_and_jacobian(self, x: F64) -> tuple[F64, F64]:
        R_cb, t_cb, p = self.unpack(x)
        Jl = so3_left_jacobian(x[3:6])
        T = self.data.T_base_flange
        b = np.einsum("nij,j->ni", T[:, :3, :3], p) + T[:, :3, 3]
        pred = b @ R_cb.T + t_cb
        e = self.data.p_cam - pred
        r = np.einsum("nij,nj->ni", self.Linv, e).ravel()
        J = np.zeros((3 * self.data.n, 9))
        for i in range(self.data.n):
            Ji = np.hstack([-np.eye(3), hat(R_cb @ b[i]) @ Jl, -R_cb @ T[i, :3, :3]])
            J[3 * i : 3 * i + 3] = self.Linv[i] @ Ji
        return r, J

    def errors(self, x: F64) -> F64:
        R_cb, t_cb, p = self.unpack(x)
        T = self.data.T_base_flange
        b = np.einsum("nij,j->ni", T[:, :3, :3], p) + T[:, :3, 3]
        return self.data.p_cam - (b @ R_cb.T + t_cb)


def _fit(data: TcpCameraData, T0: F64, p0: F64, loss: str) -> tuple[_Problem, F64, int, OptimizeResult]:
    """ML fit from (T0, p0); two passes, the second with the whitening at the first optimum.
    Returns the problem re-centred at the optimum (x = 0 there), x, evaluations, last fit."""
    problem = _Problem(data, T0, p0)
    x = np.zeros(9)
    nfev = 0
    fit = None
    for _ in range(2):
        fit = least_squares(
            lambda z, pr=problem: pr.residual_and_jacobian(z)[0],
            x,
            jac=lambda z, pr=problem: pr.residual_and_jacobian(z)[1],
            method="lm" if loss == "linear" else "trf",
            loss=loss,
            f_scale=3.0,
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=200,
        )
        nfev += int(fit.nfev)
        R_cb, t_cb, p = problem.unpack(fit.x)
        problem = _Problem(data, T_from_Rt(R_cb, t_cb), p)
    assert fit is not None
    return problem, x, nfev, fit


def _flag_outliers(data: TcpCameraData, problem: _Problem, th: TcpThresholds) -> tuple[NDArray[np.bool_], float]:
    """Sequential studentised tests: flag the worst sample, refit without it, test the rest again
    (one pass would also flag samples that the outlier's pull on the fit disturbs). Tests use a
    robust residual scale when the noise model is clearly too optimistic. Returns (flags, scale)."""
    flagged = np.zeros(data.n, dtype=bool)
    factor = 1.0
    for _ in range(max(1, data.n // 4)):
        keep = np.flatnonzero(~flagged)
        r, J = problem.residual_and_jacobian(np.zeros(9))
        stats, dofs, pvals = studentised_block_tests(J, r, [np.arange(3 * i, 3 * i + 3) for i in range(keep.size)])
        if chi2_consistency(float(r @ r), r.size - 9)[1] < th.chi2_p_value:
            pvals, factor = robust_block_pvalues(stats, dofs)
        worst = int(np.argmin(pvals))
        if pvals[worst] >= th.outlier_p_value or dofs[worst] == 0 or keep.size <= 5:
            break
        flagged[keep[worst]] = True
        sub = TcpCameraData(data.T_base_flange[~flagged], data.p_cam[~flagged], data.noise)
        R_cb, t_cb, p = problem.unpack(np.zeros(9))
        problem = _fit(sub, T_from_Rt(R_cb, t_cb), p, "linear")[0]
    return flagged, factor


def _axis(v: F64) -> F64:
    """``v`` as a unit axis with its sign fixed (largest component positive): a null-space vector has no
    sign of its own, and LAPACK builds differ in the one they return."""
    d = v / np.linalg.norm(v)
    return d if d[int(np.argmax(np.abs(d)))] > 0 else -d


def _null_space_issue(ident: Identifiability) -> Issue:
    msgs, advice = [], []
    null = np.atleast_2d(ident.null_space)
    # A null space of dimension > 1 has no unique basis (LAPACK builds may return any rotation of
    # it); rotate it so that its rows are ordered by how much TCP they carry, which separates the
    # TCP directions from the camera-rotation one whatever basis the SVD returned.
    U = np.linalg.svd(null[:, 6:9], full_matrices=True)[0]
    null = U.T @ null
    n_tcp = int(sum(np.linalg.norm(v[6:9]) > 0.5 for v in null))
    if n_tcp == 3:
        msgs.append("the whole TCP point (the flange orientation never changed)")
        advice.append("add poses rotated about two different axes (>= 20 deg each)")
    for v in null:
        rot, tcp = v[3:6], v[6:9]
        if np.linalg.norm(tcp) > 0.5:
            if n_tcp == 3:
                continue
            d = _axis(tcp)
            msgs.append(
                "the TCP component along flange axis "
                f"[{d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f}] (all orientation changes were about one axis)"
            )
            advice.append("add poses rotated about a second, different axis (>= 20 deg)")
        elif np.linalg.norm(rot) > 0.5:
            d = _axis(rot)
            msgs.append(
                f"the camera-to-base rotation about camera axis [{d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f}] "
                "(the TCP positions are collinear)"
            )
            advice.append("translate the flange along at least two non-parallel directions (seed 002)")
        else:
            msgs.append(" ".join(ident.descriptions))
            advice.append("add poses with more varied positions and orientations")
    return Issue("degenerate", "not identifiable: " + "; ".join(msgs), " and ".join(dict.fromkeys(advice)))


def cramer_rao_bound(data: TcpCameraData, T_cam_base: F64, p_flange_tcp: F64) -> tuple[F64, int]:
    """(9x9 Cramér–Rao bound of (T_cam_base, p_flange_tcp) at the given truth, information rank)."""
    problem = _Problem(data, np.asarray(T_cam_base, float), np.asarray(p_flange_tcp, float))
    return marginal_covariance(problem.residual_and_jacobian(np.zeros(9))[1])


def _closed_form_start(
    data: TcpCameraData,
    groups: list[NDArray[np.int_]],
    span: F64,
    init: Literal["auto", "seed002", "general"],
    th: TcpThresholds,
    issues: list[Issue],
) -> ClosedForm:
    """Step 2: seed 002's closed form when asked for, or (``auto``) when the pure translations span
    ``th.min_translation_span_m`` in their second direction (*span*: their singular values; a
    forced seed 002 start with a shorter span is warned about); else the general linear start."""
    has_seed_translations = span[1] >= th.min_translation_span_m
    if init == "seed002" or (init == "auto" and has_seed_translations):
        if not groups:
            raise ValueError("seed 002 start needs pure translations (same flange orientation)")
        start: ClosedForm = seed002_closed_form(data, groups)
        if not has_seed_translations:
            issues.append(
                Issue(
                    "warning",
                    f"pure translations span only {span[1] * 1e3:.1f} mm in their second direction: "
                    "seed 002's rotation step is ill-conditioned",
                    "translate the flange along at least two non-parallel directions, >= 5 cm each",
                )
            )
    else:
        start = general_linear(data)
    return start


def _covariance_and_consistency(
    problem: _Problem, x: F64, loss: str, th: TcpThresholds, metrics: dict[str, float], issues: list[Issue]
) -> tuple[F64, F64]:
    """Step 4's covariance (9x9) and the residuals' chi-square consistency (metrics added); with the
    linear loss a noise model that is too optimistic inflates the covariance and is warned about.
    Returns (the whitened Jacobian at the optimum, the covariance)."""
    r, J = problem.residual_and_jacobian(x)
    cov, rank = marginal_covariance(J)
    dof = r.size - rank
    chi2_dof, p_chi2 = chi2_consistency(float(r @ r), dof)
    metrics.update({"chi2_per_dof": chi2_dof, "chi2_p_value": p_chi2, "dof": float(dof)})
    if p_chi2 < th.chi2_p_value and loss == "linear":
        cov = cov * chi2_dof
        issues.append(
            Issue(
                "warning",
                f"residuals are {np.sqrt(chi2_dof):.1f}x the noise model (chi2/dof = {chi2_dof:.2f}); "
                "covariance inflated accordingly",
                "check camera_sigma / robot noise, and re-measure flagged samples",
            )
        )
    return J, cov


def _check_design(J: F64, cov: F64, th: TcpThresholds, metrics: dict[str, float], issues: list[Issue]) -> None:
    """Identifiability of the design (a null space becomes a ``degenerate`` issue with advice) and
    the predicted accuracy (metrics; a full-rank design determined worse than the thresholds warns)."""
    ident = analyse_identifiability(J, PARAM_NAMES, np.full(9, 1e-3), rel_tol=th.identifiability_rel_tol)
    metrics["design_rank"] = float(ident.rank)
    if not ident.full_rank:
        issues.append(_null_space_issue(ident))
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    pred_tcp = float(np.sqrt(np.sum(sd[6:9] ** 2)))
    pred_rot = float(np.degrees(np.sqrt(np.sum(sd[3:6] ** 2))))
    metrics["predicted_rms_p_flange_tcp_mm"] = pred_tcp * 1e3
    metrics["predicted_rms_T_cam_base_position_mm"] = float(np.sqrt(np.sum(sd[0:3] ** 2)) * 1e3)
    metrics["predicted_rms_T_cam_base_rotation_deg"] = pred_rot
    if ident.full_rank and (pred_tcp > th.max_predicted_tcp_rms_m or pred_rot > th.max_predicted_rotation_rms_deg):
        issues.append(
            Issue(
                "warning",
                f"weakly determined: predicted RMS error of the TCP {pred_tcp * 1e3:.2f} mm, of the camera "
                f"rotation {pred_rot:.3f} deg",
                "add poses: larger orientation changes (>= 30 deg) about two or more axes and longer pure translations",
            )
        )


def _check_outliers(
    data: TcpCameraData, problem: _Problem, th: TcpThresholds, metrics: dict[str, float], issues: list[Issue]
) -> NDArray[np.bool_]:
    """The outlier flags of :func:`_flag_outliers` as an issue (and the robust scale as a metric)."""
    outliers, factor = _flag_outliers(data, problem, th)
    if factor > 1.0:
        metrics["robust_variance_factor"] = factor
    if outliers.any():
        bad = [data.labels[i] for i in np.flatnonzero(outliers)]
        issues.append(
            Issue(
                "warning",
                f"sample(s) {', '.join(bad)} disagree with the model beyond the noise (p < {th.outlier_p_value:g})",
                f"re-measure sample(s) {', '.join(bad)} (marker detection? robot pose timing?)",
            )
        )
    return outliers


def _estimate(data: TcpCameraData, problem: _Problem, x: F64, start: ClosedForm) -> dict[str, Any]:
    """The result's ``estimate``: the calibrated transforms and TCP, the closed-form start, the noise model."""
    R_cb, t_cb, p = problem.unpack(x)
    T_cb = T_from_Rt(R_cb, t_cb)
    nz = data.noise
    return {
        "T_cam_base": T_cb,
        "T_base_cam": inv(T_cb),
        "p_flange_tcp": p,
        "closed_form_T_cam_base": start.T_cam_base,
        "closed_form_p_flange_tcp": start.p_flange_tcp,
        "noise_model": {
            "camera_sigma_m": list(nz.camera_sigma_m),
            "robot_position_sigma_m": nz.robot_position_sigma_m,
            "robot_rotation_sigma_rad": nz.robot_rotation_sigma_rad,
        },
    }


def calibrate_tcp_camera(
    data: TcpCameraData,
    *,
    thresholds: TcpThresholds | None = None,
    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = "linear",
    init: Literal["auto", "seed002", "general"] = "auto",
) -> CalibrationResult:
    """Calibrate T_cam_base and p_flange_tcp (see the module docstring).

    Raises ValueError for unusable input; quality problems come back in the verdict.
    """
    th = thresholds or TcpThresholds()
    groups = translation_groups(data, np.radians(th.pure_translation_tol_deg))
    issues = _check_input(data, groups)
    span = translation_span(data, groups)
    metrics: dict[str, float] = {
        "n_samples": float(data.n),
        "n_pure_translation_samples": float(sum(len(g) for g in groups)),
        "pure_translation_span_mm": float(span[1] * 1e3),
    }
    start = _closed_form_start(data, groups, span, init, th, issues)
    metrics["init_method_is_seed002"] = float(start.method == TRANSLATIONS_METHOD)

    problem, x, nfev, fit = _fit(data, start.T_cam_base, start.p_flange_tcp, loss)
    method = "lm" if loss == "linear" else "trf"
    if not fit.success:
        issues.append(Issue("failed", f"optimiser did not converge: {fit.message}", "check the input data"))
    J, cov = _covariance_and_consistency(problem, x, loss, th, metrics, issues)
    _check_design(J, cov, th, metrics, issues)
    outliers = _check_outliers(data, problem, th, metrics, issues)
    errs = problem.errors(x)
    en = np.linalg.norm(errs, axis=1)
    metrics.update(
        {
            "rms_error_mm": float(np.sqrt(np.mean(en**2)) * 1e3),
            "max_error_mm": float(en.max() * 1e3),
            "function_evaluations": float(nfev),
        }
    )
    return result_from_issues(
        "tcp_camera",
        issues,
        estimate=_estimate(data, problem, x, start),
        param_names=list(PARAM_NAMES),
        covariance=cov,
        residuals=errs,
        residual_names=list(RESIDUAL_NAMES),
        outliers=outliers,
        metrics=metrics,
        method=f"{start.method} + maximum likelihood (scipy least_squares {method}, loss {loss})",
        iterations=nfev,
    )
