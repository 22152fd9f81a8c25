"""Hand-eye (AX=XB) and robot-world (AX=ZB) calibration: checks, initialisation, ML, verdict.

Pipeline of :func:`calibrate_hand_eye` / :func:`calibrate_robot_world`:

1. ``validation`` - NaN, shapes, rigidity, duplicates, millimetres (raises ``HandEyeInputError``).
2. ``degeneracy`` - motion set analysed BEFORE solving; a degenerate set returns verdict
   ``degenerate`` with the reasons and the poses to add, and no estimate.
3. ``consistency`` - wrong set-up or inverted poses (verdict ``failed``), mixed units (error).
4. ``consensus`` (least median of squares over pose triples) finds gross outliers; closed forms
   (``closed_form``; all of them for ``init="auto"``, the one with the smallest median pose-chain
   cost wins) run on the consensus set.
5. ``ml`` - maximum likelihood on SE(3) with both noise models, robust loss, outlier flags,
   optional noise estimation, covariance.

Covariance scaling (``covariance_scale``): with a declared noise model the covariance is the
inverse Fisher information (``a_priori``); ``auto`` keeps it when the global chi-square test of the
residuals accepts the declared noise (two-sided, 1 %) and otherwise scales it by the variance factor
``chi2 / dof`` (and says so); ``a_posteriori`` always scales. With ``noise=None`` the noise is
estimated from the data and the covariance is always scaled by the (near 1) variance factor.

Parameters of the covariance: decoupled perturbations (``lie``) of X then Y, i.e. translation in
the parent frame (m) and rotation about parent-frame axes (rad).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from engine.transforms import angle_between
from plugins.solvers.calibration_result import CalibrationResult
from plugins.solvers.handeye.closed_form import CLOSED_FORM_METHODS, closed_form
from plugins.solvers.handeye.consensus import lmeds_consensus, pose_chain_cost
from plugins.solvers.handeye.consistency import check_setup_consistency, estimate_unit_scale
from plugins.solvers.handeye.degeneracy import MotionThresholds, analyse_motions
from plugins.solvers.handeye.lie import pose_delta
from plugins.solvers.handeye.ml import Loss, MLFit, MLOptions, refine_ml
from plugins.solvers.handeye.noise import DEFAULT_PRIOR, NoiseModel
from plugins.solvers.handeye.problem import Setup, chain_poses, check_setup, frames_of
from plugins.solvers.handeye.validation import HandEyeInputError, validate_samples

F64 = NDArray[np.float64]
CovarianceScale = Literal["auto", "a_priori", "a_posteriori"]

__all__ = [
    "RESIDUAL_NAMES",
    "AccuracyTargets",
    "calibrate_hand_eye",
    "calibrate_robot_world",
]

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
    """When the estimate's own uncertainty (1 sigma, RMS over axes) earns a ``warning``.

    Seed 000 asks for a hand-eye calibration error below 0.5 mm.
    """

    max_std_trans_m: float = 0.5e-3
    max_std_rot_rad: float = float(np.deg2rad(0.05))
    max_outlier_fraction: float = 1.0 / 3.0
    max_variance_factor: float = 25.0  # residuals 5x the declared noise -> failed
    max_noise_trans_m: float = 0.01  # estimated noise above this -> failed (not a rigid calibration)
    max_noise_rot_rad: float = float(np.deg2rad(1.0))


def _initialise(
    setup: Setup, M: F64, B: F64, methods: Sequence[str], noise: NoiseModel
) -> tuple[str, F64, F64, dict[str, tuple[F64, F64]]]:
    cands: dict[str, tuple[F64, F64]] = {}
    for m in methods:
        X, Y = closed_form(setup, M, B, m)
        if np.all(np.isfinite(X)) and np.all(np.isfinite(Y)):
            cands[m] = (X, Y)
    if not cands:
        raise FloatingPointError("every closed-form initialiser returned non-finite values")
    best = min(cands, key=lambda k: float(np.median(pose_chain_cost(setup, M, B, *cands[k], noise))))
    return best, *cands[best], cands


def _spread(d: F64) -> tuple[float, float, float, float]:
    t = np.linalg.norm(d[:, :3], axis=1)
    r = np.linalg.norm(d[:, 3:], axis=1)
    return (float(np.sqrt(np.mean(t**2))), float(t.max()), float(np.sqrt(np.mean(r**2))), float(r.max()))


def _param_names(x_name: str, y_name: str) -> list[str]:
    comps = ("tx", "ty", "tz", "rx", "ry", "rz")
    return [f"{x_name}.{c}" for c in comps] + [f"{y_name}.{c}" for c in comps]


def _calibrate(
    kind: str,
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    setup: Setup,
    noise: NoiseModel | None,
    estimate_noise: bool | None,
    init: str,
    loss: Loss,
    covariance_scale: CovarianceScale,
    motion_thresholds: MotionThresholds | None,
    accuracy: AccuracyTargets,
    seed: int,
) -> CalibrationResult:
    setup = check_setup(setup)
    if init != "auto" and init not in CLOSED_FORM_METHODS:
        raise ValueError(f"init must be 'auto' or one of {list(CLOSED_FORM_METHODS)}, got {init!r}")
    if covariance_scale not in ("auto", "a_priori", "a_posteriori"):
        raise ValueError(f"covariance_scale must be auto, a_priori or a_posteriori, got {covariance_scale!r}")
    frames = frames_of(setup)
    data = validate_samples(T_base_tcp, T_cam_target)
    M, B = data.T_base_tcp, data.T_cam_target
    reasons = list(data.warnings)
    advice: list[str] = []
    verdict = "warning" if reasons else "ok"

    motion = analyse_motions(setup, M, B, motion_thresholds)
    metrics: dict[str, float] = dict(motion.metrics)
    metrics["n_samples_given"] = float(len(np.atleast_3d(np.asarray(T_base_tcp, dtype=float))))
    if motion.verdict == "degenerate":
        return CalibrationResult(
            kind=kind,
            verdict="degenerate",
            reasons=reasons + motion.reasons,
            advice=motion.advice,
            metrics=metrics,
            method="motion analysis (not solved)",
        )
    if motion.verdict == "warning":
        verdict = "warning"
    reasons += motion.reasons
    advice += motion.advice

    sc = check_setup_consistency(setup, M, B)
    for (s, _), v in sc.mismatch.items():
        metrics[f"axis_misfit_{s}_rad"] = v
    if sc.wrong:
        return CalibrationResult(
            kind=kind,
            verdict="failed",
            reasons=[*reasons, sc.message],
            advice=[
                "check the set-up (eye_in_hand: camera on the flange; eye_to_hand: camera fixed) and that "
                "robot poses are T_base_tcp and camera poses T_cam_target; the data fit "
                f"setup={sc.best[0]!r} as given"
            ],
            metrics=metrics,
            method="consistency check (not solved)",
        )
    unit = estimate_unit_scale(setup, M, B)
    if unit is not None:
        scale, scale_sd = unit
        if not 0.5 <= scale <= 2.0 and abs(scale - 1.0) > 5.0 * scale_sd:
            side = "camera" if scale < 1 else "robot"
            raise HandEyeInputError(
                f"mixed length units: robot translations = {scale:.4g} x camera translations; the {side} "
                "poses are probably in other units (millimetres?). Convert both to metres"
            )

    estimate_noise = (noise is None) if estimate_noise is None else estimate_noise
    noise0 = noise if noise is not None else DEFAULT_PRIOR

    methods = list(CLOSED_FORM_METHODS) if init == "auto" else [init]
    weights0 = np.ones(data.n)
    best, X0, Y0, cands = _initialise(setup, M, B, methods, noise0)
    cost = pose_chain_cost(setup, M, B, X0, Y0, noise0)
    # suspicious samples, or chains far beyond the noise (a start spoilt by many outliers)
    if np.max(cost) > 3.0 * np.median(cost) or np.median(cost) > 10.0:
        consensus = lmeds_consensus(setup, M, B, noise0, seed=seed)
        if consensus is not None and 3 <= np.count_nonzero(~consensus.outliers) < data.n:
            keep = ~consensus.outliers
            weights0 = keep.astype(float)
            metrics["consensus_outliers"] = float(np.count_nonzero(consensus.outliers))
            best, X0, Y0, cands = _initialise(setup, M[keep], B[keep], methods, noise0)
    if len(cands) > 1:
        Xs = [c[0] for c in cands.values()]
        metrics["closed_form_spread_trans_m"] = max(
            float(np.linalg.norm(a[:3, 3] - b[:3, 3])) for a in Xs for b in Xs
        )
        metrics["closed_form_spread_rot_rad"] = max(
            angle_between(a[:3, :3], b[:3, :3]) for a in Xs for b in Xs
        )

    fit = refine_ml(
        setup,
        M,
        B,
        X0,
        Y0,
        noise0,
        options=MLOptions(loss=loss, estimate_noise=estimate_noise),
        initial_weights=weights0,
    )
    return _assemble(
        kind, setup, frames.x_name, frames.y_name, data.index, M, B, fit, best, loss, estimate_noise,
        covariance_scale, accuracy, verdict, reasons, advice, metrics,
    )  # fmt: skip


def _assemble(
    kind: str,
    setup: Setup,
    x_name: str,
    y_name: str,
    index: NDArray[np.int64],
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
    n = M.shape[0]
    inl = ~fit.outliers
    reasons = reasons + fit.notes
    # ---- covariance scaling
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
            advice.append(
                "state the robot and camera noise that matches the data, or pass noise=None to estimate it"
            )
    cov = fit.covariance * cov_factor

    # ---- pose-chain spread (each sample's own estimate of Y against the fit)
    d_chain = pose_delta(chain_poses(setup, M, fit.X, B), np.broadcast_to(fit.Y, M.shape))
    t_rms, t_max, r_rms, r_max = _spread(d_chain[inl])
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    metrics.update(
        {
            "n_samples": float(n),
            "n_inliers": float(np.count_nonzero(inl)),
            "n_outliers": float(np.count_nonzero(fit.outliers)),
            "chain_spread_trans_rms_m": t_rms,
            "chain_spread_trans_max_m": t_max,
            "chain_spread_rot_rms_rad": r_rms,
            "chain_spread_rot_max_rad": r_max,
            "camera_residual_trans_rms_m": float(
                np.sqrt(np.mean(np.sum(fit.e_camera[inl, :3] ** 2, axis=1)))
            ),
            "camera_residual_rot_rms_rad": float(
                np.sqrt(np.mean(np.sum(fit.e_camera[inl, 3:] ** 2, axis=1)))
            ),
            "robot_residual_trans_rms_m": float(np.sqrt(np.mean(np.sum(fit.e_robot[inl, :3] ** 2, axis=1)))),
            "robot_residual_rot_rms_rad": float(np.sqrt(np.mean(np.sum(fit.e_robot[inl, 3:] ** 2, axis=1)))),
            "chi2": fit.chi2,
            "dof": float(fit.dof),
            "variance_factor": vf,
            "covariance_factor": cov_factor,
            "std_x_trans_m": float(np.sqrt(np.sum(std[0:3] ** 2))),
            "std_x_rot_rad": float(np.sqrt(np.sum(std[3:6] ** 2))),
            "std_y_trans_m": float(np.sqrt(np.sum(std[6:9] ** 2))),
            "std_y_rot_rad": float(np.sqrt(np.sum(std[9:12] ** 2))),
            "noise_robot_trans_m": float(np.mean(fit.noise.robot.trans_sigma)),
            "noise_robot_rot_rad": float(np.mean(fit.noise.robot.rot_sigma)),
            "noise_camera_trans_m": float(np.mean(fit.noise.camera.trans_sigma)),
            "noise_camera_rot_rad": float(np.mean(fit.noise.camera.rot_sigma)),
            "noise_estimated": float(noise_estimated),
            "noise_groups_estimated": float(fit.noise_groups_estimated),
            "threshold_scale": fit.threshold_scale,
            "nfev": float(fit.nfev),
        }
    )

    # ---- camera length scale on the inliers (wrong target size or intrinsics scale the camera)
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

    # ---- verdict
    if not fit.converged:
        verdict = "failed"
        reasons.append("the maximum-likelihood refinement did not converge")
    n_out = int(np.count_nonzero(fit.outliers))
    if n_out:
        idx = ", ".join(str(int(i)) for i in index[fit.outliers][:12])
        reasons.append(f"{n_out} outlier sample(s) left out of the estimate: {idx}")
        advice.append("inspect the outlier samples (detection, robot/camera time sync, target slipped)")
        verdict = "warning" if verdict == "ok" else verdict
        if n_out > accuracy.max_outlier_fraction * n:
            verdict = "failed"
            reasons.append(
                f"too many outliers ({n_out} of {n}): the data are not consistent with one calibration"
            )
    if not noise_estimated and np.isfinite(vf) and vf > accuracy.max_variance_factor:
        verdict = "failed"
        reasons.append(
            f"residuals are {np.sqrt(vf):.1f}x the declared noise: the model does not fit the data"
        )
    worst_t = max(metrics["noise_robot_trans_m"], metrics["noise_camera_trans_m"])
    worst_r = max(metrics["noise_robot_rot_rad"], metrics["noise_camera_rot_rad"])
    if noise_estimated and (worst_t > accuracy.max_noise_trans_m or worst_r > accuracy.max_noise_rot_rad):
        verdict = "failed"
        reasons.append(
            f"the data need {worst_t * 1e3:.1f} mm / {np.rad2deg(worst_r):.2f} deg of pose noise to fit one "
            f"rigid hand-eye transform (limits {accuracy.max_noise_trans_m * 1e3:.0f} mm / "
            f"{np.rad2deg(accuracy.max_noise_rot_rad):.1f} deg): wrong set-up, frames, time sync or a "
            "moving target"
        )
    if (
        metrics["std_x_trans_m"] > accuracy.max_std_trans_m
        or metrics["std_x_rot_rad"] > accuracy.max_std_rot_rad
    ):
        verdict = "warning" if verdict == "ok" else verdict
        reasons.append(
            f"{x_name} uncertainty {metrics['std_x_trans_m'] * 1e3:.3f} mm / "
            f"{np.rad2deg(metrics['std_x_rot_rad']):.4f} deg (1 sigma) exceeds the target "
            f"{accuracy.max_std_trans_m * 1e3:.2f} mm / {np.rad2deg(accuracy.max_std_rot_rad):.3f} deg"
        )
        advice.append("add poses with larger rotations about different axes, or reduce the measurement noise")
    if not (np.all(np.isfinite(fit.X)) and np.all(np.isfinite(fit.Y)) and np.all(np.isfinite(cov))):
        verdict = "failed"
        reasons.append("non-finite estimate")

    residuals = np.column_stack(
        [index.astype(float), d_chain, fit.e_robot, fit.e_camera, fit.s2, fit.weights]
    )
    return CalibrationResult(
        kind=kind,
        verdict=verdict,  # type: ignore[arg-type]
        estimate={x_name: fit.X, y_name: fit.Y, "setup": setup},
        param_names=_param_names(x_name, y_name),
        covariance=cov,
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


def calibrate_hand_eye(
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    setup: Setup = "eye_in_hand",
    noise: NoiseModel | None = None,
    estimate_noise: bool | None = None,
    init: str = "auto",
    loss: Loss = "huber",
    covariance_scale: CovarianceScale = "auto",
    motion_thresholds: MotionThresholds | None = None,
    accuracy: AccuracyTargets | None = None,
    seed: int = 0,
) -> CalibrationResult:
    """Hand-eye calibration (AX = XB) from robot poses T_base_tcp and camera observations T_cam_target.

    Args:
        T_base_tcp: robot flange/TCP poses in the base frame, ``(n, 4, 4)`` in metres.
        T_cam_target: calibration target poses seen by the camera, ``(n, 4, 4)`` in metres.
        setup: ``"eye_in_hand"`` (estimates ``T_tcp_cam`` and the fixed ``T_base_target``) or
            ``"eye_to_hand"`` (estimates ``T_base_cam`` and the target on the flange ``T_tcp_target``).
        noise: declared robot / camera noise; ``None`` estimates it from the data.
        estimate_noise: force noise estimation on or off (default: on exactly when ``noise`` is None).
        init: ``"auto"`` (best of all closed forms) or one of ``tsai_lenz``, ``park_martin``,
            ``daniilidis``, ``shah``.
        loss: ``"huber"`` (default), ``"cauchy"`` or ``"linear"`` (plain ML, no down-weighting).
        covariance_scale: see the module docstring.
        seed: seed of the random choice of pose triples in the outlier consensus (``consensus``).

    Returns:
        CalibrationResult with estimate ``{x_name, y_name, "setup"}``, 12x12 covariance, per-sample
        residuals (``RESIDUAL_NAMES``), outlier flags, verdict, reasons, advice and metrics.

    Raises:
        HandEyeInputError: unusable input (NaN, shapes, non-rigid poses, millimetres, mixed units).
    """
    return _calibrate(
        "hand_eye", T_base_tcp, T_cam_target, setup=setup, noise=noise, estimate_noise=estimate_noise,
        init=init, loss=loss, covariance_scale=covariance_scale, motion_thresholds=motion_thresholds,
        accuracy=accuracy or AccuracyTargets(), seed=seed,
    )  # fmt: skip


def calibrate_robot_world(
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    setup: Setup = "eye_in_hand",
    noise: NoiseModel | None = None,
    estimate_noise: bool | None = None,
    init: str = "shah",
    loss: Loss = "huber",
    covariance_scale: CovarianceScale = "auto",
    motion_thresholds: MotionThresholds | None = None,
    accuracy: AccuracyTargets | None = None,
    seed: int = 0,
) -> CalibrationResult:
    """Robot-world + hand-eye calibration (AX = ZB): X and Z estimated jointly, both reported.

    Same data and arguments as :func:`calibrate_hand_eye`; ``A_i = T_base_tcp_i`` (or its inverse
    for eye-to-hand), ``B_i = T_cam_target_i^-1``, X the hand-eye transform and Z = ``T_base_target``
    (eye-in-hand) or ``T_tcp_target`` (eye-to-hand). Initialised with Shah's Kronecker closed form by
    default; the ML refinement and the result are those of the hand-eye solver.
    """
    return _calibrate(
        "robot_world", T_base_tcp, T_cam_target, setup=setup, noise=noise, estimate_noise=estimate_noise,
        init=init, loss=loss, covariance_scale=covariance_scale, motion_thresholds=motion_thresholds,
        accuracy=accuracy or AccuracyTargets(), seed=seed,
    )  # fmt: skip
