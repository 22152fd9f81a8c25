"""Turning an ML fit into a CalibrationResult: covariance scaling, metrics, residual table, verdict.

Covariance scaling (``covariance_scale``): with a declared noise model the covariance is the
inverse Fisher information (``a_priori``); ``auto`` keeps it when the global chi-square test of the
residuals accepts the declared noise (two-sided, 1 %) and otherwise scales it by the variance factor
``chi2 / dof`` (and says so); ``a_posteriori`` always scales. With the noise estimated from the
data the covariance is always scaled by the (near 1) variance factor.

Confidence regions: a scaled covariance is an estimate, so the region of k parameters is
``d^T C^-1 d <= k F(k, nu; level) / lambda`` (``CalibrationResult.confidence_threshold``) with
``metrics["covariance_dof"]`` = ``nu`` and ``metrics["covariance_f_scale"]`` = ``lambda`` for X
(6 parameters; ``_xy`` for X and Y, 12). With the noise estimated these are Kenward-Roger's, and
the covariance itself is the Kenward-Roger adjusted one (``variance``;
``metrics["covariance_kr_inflation"]`` says by how much it widened X's); for a declared noise
scaled by the variance factor, ``nu = dof`` and ``lambda = 1`` (exact). Absent when the covariance
is known (chi-square).

Parameters of the covariance: decoupled perturbations (:mod:`engine.transforms`) of X then Y, i.e. translation in
the parent frame (m) and rotation about parent-frame axes (rad).

Verdict rules (on top of the input and motion checks): ``failed`` when the ML did not converge,
the outliers agree among themselves on another calibration (never on their count alone: a minority
that agrees among random outliers is still the calibration), the residuals exceed the declared
noise by more than ``sqrt(max_variance_factor)``, or the estimated noise of the robot or of the
camera exceeds its limit (``max_robot_noise_*``, ``max_camera_noise_*``: the noise a real sensor of
that kind can have; beyond it the data do not fit one rigid transform); ``warning`` for outliers
(more than chance flags on clean data: ``chance_flags_level``), a
declared noise that does not fit, a camera length scale off 1, or an uncertainty of X above
``max_std_*`` (seed 000: hand-eye error below 0.5 mm). Samples are named by the caller's ids
(``labels``; they also go into ``estimate["sample_labels"]``, one per residual row).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from engine.transforms import pose_delta
from plugins.calibration.handeye.consensus import second_group
from plugins.calibration.handeye.consistency import estimate_unit_scale
from plugins.calibration.handeye.ml import DOF_PER_SAMPLE, Loss, MLFit
from plugins.calibration.handeye.problem import Setup, chain_poses
from plugins.calibration.result import CalibrationResult

F64 = NDArray[np.float64]
CovarianceScale = Literal["auto", "a_priori", "a_posteriori"]

__all__ = ["RESIDUAL_NAMES", "AccuracyTargets", "CovarianceScale", "assemble_result"]

RESIDUAL_NAMES: list[str] = [
    "sample_index",
    *(f"chain_{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")),
    *(f"robot_{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")),
    *(f"camera_{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")),
    "mahalanobis2",
    "weight",
]


@dataclass(frozen=True)
class AccuracyTargets:
    """Limits of the verdict: when the estimate's own uncertainty (1 sigma, RMS over axes) earns a
    ``warning`` (seed 000 asks for a hand-eye calibration error below 0.5 mm), and when a result is
    ``failed``.

    The noise limits are the largest pose noise (1 sigma per axis, as estimated from the residuals)
    a sensor of that kind can plausibly have; an estimate beyond one means the data do not fit one
    rigid transform (wrong frames, time sync, a target that moved). Camera: marker and AR-tag poses
    on real cameras scatter by a degree or more in rotation and by millimetres in depth (MoveIt's
    and camodocal's real data need 0.05 deg / 2.7 mm and 1.1 deg / 2.0 mm), so the default allows
    5 deg / 20 mm. Robot: an arm's reported pose repeats to hundredths of a degree and of a
    millimetre; 1 deg / 10 mm is already far outside any working arm.
    """

    max_std_trans_m: float = 0.5e-3
    max_std_rot_rad: float = float(np.deg2rad(0.05))
    # more outliers than this fraction: the reasons say the estimate rests on a minority (the
    # consensus, ``consensus``, tolerates more; a second group that agrees is what refuses it)
    max_outlier_fraction: float = 0.5
    # outlier flags this likely or likelier by chance alone (binomial, the ML's outlier quantile) on
    # data without outliers are named but earn no warning
    chance_flags_level: float = 0.01
    max_variance_factor: float = 25.0  # residuals 5x the declared noise -> failed
    max_camera_noise_rot_rad: float = float(np.deg2rad(5.0))  # estimated noise above these -> failed
    max_camera_noise_trans_m: float = 0.02
    max_robot_noise_rot_rad: float = float(np.deg2rad(1.0))
    max_robot_noise_trans_m: float = 0.01

    def noise_limits_text(self) -> str:
        """The noise limits for people: ``robot 1 deg / 10 mm, camera 5 deg / 20 mm``."""
        return (
            f"robot {np.rad2deg(self.max_robot_noise_rot_rad):.3g} deg / {self.max_robot_noise_trans_m * 1e3:.3g} mm, "
            f"camera {np.rad2deg(self.max_camera_noise_rot_rad):.3g} deg / {self.max_camera_noise_trans_m * 1e3:.3g} mm"
        )


_CAMERA_AXES = ("tx_m", "ty_m", "tz_m", "rx_rad", "ry_rad", "rz_rad")


def std_metrics(covariance: F64) -> dict[str, float]:
    """The 1-sigma of X and of Y from their 12 x 12 covariance, translation and rotation each the
    root sum of its three axes' variances: ``std_x_trans_m``, ``std_x_rot_rad``, ``std_y_*``."""
    std = np.sqrt(np.clip(np.diag(covariance)[:12], 0.0, None))
    return {
        f"std_{name}": float(np.sqrt(np.sum(std[k : k + 3] ** 2)))
        for name, k in (("x_trans_m", 0), ("x_rot_rad", 3), ("y_trans_m", 6), ("y_rot_rad", 9))
    }


def _listed(ids: list[str]) -> str:
    """Sample ids for a reason: the first 12, and how many in all beyond that."""
    return ", ".join(ids[:12]) + (f" ... ({len(ids)} in all)" if len(ids) > 12 else "")


def _spread(d: F64) -> tuple[float, float, float, float]:
    t = np.linalg.norm(d[:, :3], axis=1)
    r = np.linalg.norm(d[:, 3:], axis=1)
    return (float(np.sqrt(np.mean(t**2))), float(t.max()), float(np.sqrt(np.mean(r**2))), float(r.max()))


def _param_names(x_name: str, y_name: str) -> list[str]:
    comps = ("tx", "ty", "tz", "rx", "ry", "rz")
    return [f"{x_name}.{c}" for c in comps] + [f"{y_name}.{c}" for c in comps]


def _check_noise_limits(
    fit: MLFit, accuracy: AccuracyTargets, verdict: str, reasons: list[str], advice: list[str]
) -> str:
    """``failed`` (with the reason) when the estimated robot or camera noise exceeds its limit."""
    over = []
    for who, pose_noise, max_rot, max_trans in (
        ("robot", fit.noise.robot, accuracy.max_robot_noise_rot_rad, accuracy.max_robot_noise_trans_m),
        ("camera", fit.noise.camera, accuracy.max_camera_noise_rot_rad, accuracy.max_camera_noise_trans_m),
    ):
        rot, trans = float(np.max(pose_noise.rot_sigma)), float(np.max(pose_noise.trans_sigma))
        if rot > max_rot or trans > max_trans:
            over.append(
                f"{who} {np.rad2deg(rot):.2f} deg / {trans * 1e3:.1f} mm (limit {np.rad2deg(max_rot):.3g} deg / "
                f"{max_trans * 1e3:.3g} mm)"
            )
    if not over:
        return verdict
    reasons.append(
        f"the data need a pose noise of {' and '.join(over)} per axis to fit one rigid hand-eye transform: "
        "wrong frames, time sync or a target that moved"
    )
    advice.append(
        "if the sensor really is that noisy (small markers far away), raise its noise limit "
        "(AccuracyTargets.max_*_noise_*; vgr calibrate: --max-camera-noise / --max-robot-noise DEG MM)"
    )
    return "failed"


class _ScaledCovariance(NamedTuple):
    """Covariance scaling's outcome (module docstring): the variance factor ``chi2 / dof``, the factor
    applied, the scaled covariance and the degrees of freedom of its confidence regions (metrics)."""

    variance_factor: float
    factor: float
    matrix: F64
    dof_metrics: dict[str, float]


def _scale_covariance(
    fit: MLFit,
    noise_estimated: bool,
    covariance_scale: CovarianceScale,
    verdict: str,
    reasons: list[str],
    advice: list[str],
) -> tuple[_ScaledCovariance, str]:
    """The covariance scaled as ``covariance_scale`` asks, and the verdict (``warning``, with the
    reason, for no redundancy or a declared noise the chi-square test rejects)."""
    vf = fit.chi2 / fit.dof if fit.dof > 0 else float("nan")
    cov_factor = 1.0
    if fit.dof <= 0:
        reasons.append("no redundancy (dof <= 0): the covariance cannot be checked against the residuals")
        verdict = "warning"
    elif noise_estimated or covariance_scale == "a_posteriori":
        cov_factor = vf
    elif covariance_scale == "auto":
        lo, hi = stats.chi2.ppf([0.005, 0.995], fit.dof) / fit.dof
        if not lo <= vf <= hi:
            cov_factor = vf
            verdict = "warning"
            reasons.append(
                f"declared noise does not fit the residuals: variance factor {vf:.3g} (residuals "
                f"{np.sqrt(vf):.2f}x the declared sigmas, accepted range {lo:.2f}-{hi:.2f}); "
                "covariance scaled by it"
            )
            advice.append("state the robot and camera noise that matches the data, or pass noise=None to estimate it")
    cov = fit.covariance * cov_factor
    # degrees of freedom of the covariance (confidence regions use F(k, dof) instead of chi2(k))
    cov_dof: dict[str, float] = {}
    if noise_estimated and fit.dof > 0 and np.isfinite(fit.dof_x):
        cov_dof = {
            "covariance_dof": fit.dof_x,
            "covariance_f_scale": fit.f_scale_x,
            "covariance_dof_xy": fit.dof_xy,
            "covariance_f_scale_xy": fit.f_scale_xy,
            "covariance_kr_inflation": fit.kr_inflation_x,
        }
    elif cov_factor != 1.0 or (covariance_scale == "a_posteriori" and fit.dof > 0):
        cov_dof = {"covariance_dof": float(fit.dof), "covariance_dof_xy": float(fit.dof)}
    return _ScaledCovariance(vf, cov_factor, cov, cov_dof), verdict


def _fit_metrics(
    n: int,
    fit: MLFit,
    d_chain: F64,
    cov: _ScaledCovariance,
    noise_estimated: bool,
    accuracy: AccuracyTargets,
) -> dict[str, float]:
    """The metrics of the fit: sample counts, pose-chain spread and residual RMS over the inliers,
    chi-square, covariance scaling, the estimate's 1-sigma, the noise and its limits."""
    inl = ~fit.outliers
    t_rms, t_max, r_rms, r_max = _spread(d_chain[inl])
    return {
        "n_samples": float(n),
        "n_inliers": float(np.count_nonzero(inl)),
        "n_outliers": float(np.count_nonzero(fit.outliers)),
        "chain_spread_trans_rms_m": t_rms,
        "chain_spread_trans_max_m": t_max,
        "chain_spread_rot_rms_rad": r_rms,
        "chain_spread_rot_max_rad": r_max,
        "camera_residual_trans_rms_m": float(np.sqrt(np.mean(np.sum(fit.e_camera[inl, :3] ** 2, axis=1)))),
        "camera_residual_rot_rms_rad": float(np.sqrt(np.mean(np.sum(fit.e_camera[inl, 3:] ** 2, axis=1)))),
        "robot_residual_trans_rms_m": float(np.sqrt(np.mean(np.sum(fit.e_robot[inl, :3] ** 2, axis=1)))),
        "robot_residual_rot_rms_rad": float(np.sqrt(np.mean(np.sum(fit.e_robot[inl, 3:] ** 2, axis=1)))),
        "chi2": fit.chi2,
        "dof": float(fit.dof),
        "variance_factor": cov.variance_factor,
        "covariance_factor": cov.factor,
        **cov.dof_metrics,
        **std_metrics(cov.matrix),
        "noise_robot_trans_m": float(np.mean(fit.noise.robot.trans_sigma)),
        "noise_robot_rot_rad": float(np.mean(fit.noise.robot.rot_sigma)),
        "noise_camera_trans_m": float(np.mean(fit.noise.camera.trans_sigma)),
        "noise_camera_rot_rad": float(np.mean(fit.noise.camera.rot_sigma)),
        # per axis of the camera frame (z: the optical axis), as estimated or declared
        **{f"noise_camera_sigma_{c}": float(v) for c, v in zip(_CAMERA_AXES, fit.noise.camera.sigmas6(), strict=True)},
        # per-sample camera covariances (the sigmas above: their median per axis) and their factor
        **(
            {"camera_covariances_given": 1.0, "noise_camera_covariance_factor": fit.camera_covariance_factor}
            if fit.noise.camera_covariances is not None
            else {}
        ),
        "noise_estimated": float(noise_estimated),
        "noise_groups_estimated": float(fit.noise_groups_estimated),
        "threshold_scale": fit.threshold_scale,
        # the outlier test's tail (``tails``): 1 when the costs showed a t tail, its dof and bound
        **_tail_metrics(fit),
        "nfev": float(fit.nfev),
        "noise_limit_robot_rot_rad": accuracy.max_robot_noise_rot_rad,
        "noise_limit_robot_trans_m": accuracy.max_robot_noise_trans_m,
        "noise_limit_camera_rot_rad": accuracy.max_camera_noise_rot_rad,
        "noise_limit_camera_trans_m": accuracy.max_camera_noise_trans_m,
    }


def _check_unit_scale(
    setup: Setup, M: F64, B: F64, fit: MLFit, metrics: dict[str, float], verdict: str, reasons: list[str]
) -> str:
    """The camera length scale on the inliers into the metrics (wrong target size or intrinsics scale
    the camera); ``warning``, with the reason, when it is off 1."""
    inl = ~fit.outliers
    unit = estimate_unit_scale(setup, M[inl], B[inl], robust=False) if np.count_nonzero(inl) >= 3 else None
    if unit is not None:
        scale, scale_sd = unit
        metrics["unit_scale_robot_per_camera"] = scale
        metrics["unit_scale_std"] = scale_sd
        if abs(scale - 1.0) > max(5.0 * scale_sd, 0.005):
            verdict = "warning" if verdict == "ok" else verdict
            reasons.append(
                f"camera translations look scaled by {1.0 / scale:.4f} relative to the robot's "
                f"(+-{scale_sd / scale**2:.4f}): check the calibration-target size and the camera intrinsics"
            )
    return verdict


def _tail_metrics(fit: MLFit) -> dict[str, float]:
    """``noise_heavy_tail`` (1: the outlier bound rests on a t tail of the costs, ``tails``) and,
    then, ``noise_tail_dof`` and ``outlier_bound`` (studentized cost)."""
    if fit.tail is None:
        return {}
    out = {"noise_heavy_tail": float(fit.tail.heavy), "outlier_bound": fit.tail.threshold}
    if fit.tail.heavy:
        out["noise_tail_dof"] = fit.tail.nu
    return out


def _chance_of_flags(fit: MLFit, scale: float) -> float:
    """How likely flags like *fit*'s are on data without outliers: the smaller of the chance of as
    many flags (binomial, at the outlier quantile) and of a sample as far out as the farthest flagged
    one among all (Sidak: ``1 - (1 - p)^n``, ``p`` its chi-square(6) tail at the noise *scale*, or
    its tail under the costs' t model when the outlier test found one)."""
    n, n_out = len(fit.outliers), int(np.count_nonzero(fit.outliers))
    p_count = float(stats.binom.sf(n_out - 1, n, 1.0 - fit.outlier_quantile))
    worst = float(np.max(fit.s2[fit.outliers]))
    tail = getattr(fit, "tail", None)  # (None for a fit without an outlier test on estimated noise)
    if tail is not None and tail.heavy:  # the costs' own t tail (``tails``)
        p_worst = float(stats.f.sf(worst / (tail.tau * DOF_PER_SAMPLE), DOF_PER_SAMPLE, tail.nu))
    else:
        p_worst = float(stats.chi2.sf(worst / scale, DOF_PER_SAMPLE))
    return min(p_count, float(-np.expm1(n * np.log1p(-min(p_worst, 1.0 - 1e-16)))))


def _check_outliers(
    fit: MLFit,
    labels: list[str],
    loss: Loss,
    scale: float,
    accuracy: AccuracyTargets,
    verdict: str,
    reasons: list[str],
    advice: list[str],
) -> str:
    """Outlier samples named in the reasons: ``warning``, unless as many flags are likely by chance
    (``chance_flags_level``); never ``failed`` on the count alone. Beyond ``max_outlier_fraction``
    the reasons say the estimate rests on a minority; only evidence that the outliers hold another
    calibration (:func:`_check_second_group`) refuses it."""
    n = len(fit.outliers)
    n_out = int(np.count_nonzero(fit.outliers))
    if not n_out:
        return verdict
    idx = _listed([labels[k] for k in np.flatnonzero(fit.outliers)])
    fate = "kept in the estimate (loss='linear')" if loss == "linear" else "left out of the estimate"
    outlier_quantile = fit.outlier_quantile
    p_chance = _chance_of_flags(fit, scale)
    if p_chance >= accuracy.chance_flags_level:
        reasons.append(
            f"{n_out} sample(s) beyond the {outlier_quantile:.1%} quantile of the noise, {fate}: {idx} "
            f"(as many are flagged by chance in {n} samples with probability {p_chance:.2g})"
        )
        return verdict
    reasons.append(f"{n_out} outlier sample(s) {fate}: {idx}")
    advice.append("inspect the outlier samples (detection, robot/camera time sync, target slipped)")
    verdict = "warning" if verdict == "ok" else verdict
    if n_out > accuracy.max_outlier_fraction * n:
        reasons.append(
            f"{n_out} of {n} samples are outliers: the estimate rests on the {n - n_out} that agree; it is "
            "refused only if the outliers agree among themselves on another calibration (checked next)"
        )
    return verdict


def _check_second_group(
    setup: Setup,
    M: F64,
    B: F64,
    fit: MLFit,
    labels: list[str],
    metrics: dict[str, float],
    verdict: str,
    reasons: list[str],
    advice: list[str],
) -> str:
    """``failed`` when the outliers agree among themselves on another calibration (``consensus``):
    the data hold two calibrations, and which one is the cell's cannot be told from them."""
    group = second_group(setup, M, B, fit.outliers, fit.X, fit.Y, fit.noise)
    k = int(np.count_nonzero(group))
    metrics["second_group_samples"] = float(k)
    if not k:
        return verdict
    shown = _listed([labels[i] for i in np.flatnonzero(group)])
    reasons.append(
        f"{k} of the outlier samples agree among themselves on another calibration ({shown}): the "
        "target or the camera moved between samples, so the data hold two calibrations"
    )
    advice.append("keep the target and the camera mount fixed while sampling, then sample again")
    return "failed"


def _judge(
    fit: MLFit,
    cov: _ScaledCovariance,
    x_name: str,
    labels: list[str],
    loss: Loss,
    noise_estimated: bool,
    accuracy: AccuracyTargets,
    metrics: dict[str, float],
    verdict: str,
    reasons: list[str],
    advice: list[str],
) -> str:
    """The verdict rules of the module docstring on the fit, in order; the reasons and advice say why."""
    vf = cov.variance_factor
    if not fit.converged:
        verdict = "failed"
        reasons.append("the maximum-likelihood refinement did not converge")
    # (the flags' noise scale: the estimated noise's own, or the robust factor on a declared one)
    scale = 1.0 if noise_estimated else fit.threshold_scale
    verdict = _check_outliers(fit, labels, loss, scale, accuracy, verdict, reasons, advice)
    if not noise_estimated and np.isfinite(vf) and vf > accuracy.max_variance_factor:
        verdict = "failed"
        reasons.append(f"residuals are {np.sqrt(vf):.1f}x the declared noise: the model does not fit the data")
    if noise_estimated:
        verdict = _check_noise_limits(fit, accuracy, verdict, reasons, advice)
    over = []
    if metrics["std_x_trans_m"] > accuracy.max_std_trans_m:
        over.append(
            f"translation {metrics['std_x_trans_m'] * 1e3:.3f} mm (1 sigma) exceeds the target "
            f"{accuracy.max_std_trans_m * 1e3:.2f} mm"
        )
    if metrics["std_x_rot_rad"] > accuracy.max_std_rot_rad:
        over.append(
            f"rotation {np.rad2deg(metrics['std_x_rot_rad']):.4f} deg (1 sigma) exceeds the target "
            f"{np.rad2deg(accuracy.max_std_rot_rad):.3f} deg"
        )
    if over:
        verdict = "warning" if verdict == "ok" else verdict
        reasons.append(f"{x_name} uncertainty: {' and '.join(over)}")
        advice.append("add poses with larger rotations about different axes, or reduce the measurement noise")
    if not (np.all(np.isfinite(fit.X)) and np.all(np.isfinite(fit.Y)) and np.all(np.isfinite(cov.matrix))):
        verdict = "failed"
        reasons.append("non-finite estimate")
    return verdict


def assemble_result(
    kind: str,
    setup: Setup,
    x_name: str,
    y_name: str,
    index: NDArray[np.int64],
    labels: list[str],
    M: F64,
    B: F64,
    fit: MLFit,
    init_method: str,
    loss: Loss,
    noise_estimated: bool,
    covariance_scale: CovarianceScale,
    accuracy: AccuracyTargets,
    verdict: str,
    reasons: list[str],
    advice: list[str],
    metrics: dict[str, float],
) -> CalibrationResult:
    """The result of one ML fit (module docstring): ``reasons`` is extended into a new list, ``advice``
    and ``metrics`` are added to in place."""
    reasons = reasons + fit.notes
    cov, verdict = _scale_covariance(fit, noise_estimated, covariance_scale, verdict, reasons, advice)
    # pose-chain spread: each sample's own estimate of Y against the fit
    d_chain = pose_delta(chain_poses(setup, M, fit.X, B), np.broadcast_to(fit.Y, M.shape))
    metrics.update(_fit_metrics(M.shape[0], fit, d_chain, cov, noise_estimated, accuracy))
    verdict = _check_unit_scale(setup, M, B, fit, metrics, verdict, reasons)
    verdict = _judge(fit, cov, x_name, labels, loss, noise_estimated, accuracy, metrics, verdict, reasons, advice)
    verdict = _check_second_group(setup, M, B, fit, labels, metrics, verdict, reasons, advice)
    residuals = np.column_stack([index.astype(float), d_chain, fit.e_robot, fit.e_camera, fit.s2, fit.weights])
    return CalibrationResult(
        kind=kind,
        verdict=verdict,  # type: ignore[arg-type]
        estimate={x_name: fit.X, y_name: fit.Y, "setup": setup, "sample_labels": list(labels)},
        param_names=_param_names(x_name, y_name),
        covariance=cov.matrix,
        residuals=residuals,
        residual_names=list(RESIDUAL_NAMES),
        outliers=fit.outliers.copy(),
        reasons=reasons,
        advice=advice,
        metrics=metrics,
        method=f"{init_method} + ML (errors-in-variables, {loss} loss"
        + (", noise estimated)" if noise_estimated else ")"),
        iterations=fit.nfev,
    )
