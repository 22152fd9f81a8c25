"""Hand-eye (AX=XB) and robot-world (AX=ZB) calibration from images of a board and robot poses.

Pipeline of :func:`calibrate_handeye_images`:

1. Pairing: image ``k`` (in the order given; a folder's images sorted by name) belongs to robot pose
   ``k`` of the pose file. Different counts are an error naming both; images where the board was
   not found are listed and their poses dropped.
2. Intrinsics: the given camera, or :func:`.intrinsics.calibrate_intrinsics` on the same images.
3. Board pose per image with its 6x6 covariance (:func:`.board_pose.board_pose`, the corner noise
   from the intrinsic fit's RMS). A camera that moved mirrored to the robot (robot translations
   = -1 x the camera's: mirrored images, or the wrong set-up) fails here, saying so.
4. vgr's maximum-likelihood hand-eye solver (:mod:`plugins.calibration.handeye`) on the pose pairs,
   each view's camera residual whitened by its own board-pose covariance (``camera_covariances``:
   a far or oblique view's PnP error is larger, mostly along its line of sight, and correlated; the
   solver estimates one common factor of them with the robot's noise), and the solver's checks
   apply (degenerate motion, wrong set-up, mixed units, scaled camera: a wrong square size is
   reported as "square size?" with the factor the data ask for, and fails). When the
   solver's own result is not usable although it solved (it did not converge, or flagged many views
   on data whose robot poses are nearly exact), the declared-noise solution and the closed forms are
   tried as starts too, and the pixel refinement keeps the one that fits the corners best.
5. Refinement in pixels (:func:`.reprojection.refine_reprojection`): ``X``, ``Y`` and optionally the
   intrinsics, minimising the corners' reprojection error through the robot poses as given (the
   maximum-likelihood estimate if the robot poses were exact).
6. The same refinement with every robot pose corrected under a prior (``robot_noise="estimate"``):
   the corner noise and the robot's translation / rotation noise are estimated from the corners
   (variance components). It gives (a) the covariance reported for step 5's estimate
   (:func:`.reprojection.robot_aware_covariance`: corner and robot noise propagated through the
   exact-robot fit), (b) the outliers: views whose robot-pose correction is far beyond the others'
   and whose corners fit badly through their robot pose (:func:`moved_views`: the board moved, the
   pose is not the image's, a poor detection) are listed and left out, and the rest checked again,
   (c) with ``model_robot_noise=True``, the estimate itself (its own covariance). Measured
   (docs/calibration_boards.md): on kuka_2 modelling the robot noise lowers the rotation spread of the
   board's world pose from 0.17 to 0.053 deg but raises the held-out reprojection from 1.26 to 1.85 px
   (its robot's errors are not independent between poses, and the exact-robot fit absorbs part of
   them into X and Y), so step 5's estimate stays the default.
7. Figures: fit and leave-one-view-out reprojection RMS (px), the spread of the board's world pose
   over the views, the estimated noise, and a verdict.

The result is a :class:`CalibrationResult` (kind ``hand_eye`` / ``robot_world``) whose estimate
holds ``T_tcp_cam`` and ``T_base_target`` (eye in hand) or ``T_base_cam`` and ``T_tcp_target`` (eye
to hand) with their 1-sigma (step 6), ``camera``, the images used and the outlier views left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from plugins.calibration.boards.board_pose import BoardPose, board_pose
from plugins.calibration.boards.detect import Detection, Detections, Rejection
from plugins.calibration.boards.reprojection import (
    ESTIMATE,
    Refinement,
    RobotNoise,
    holdout_rms,
    refine_reprojection,
    robot_aware_covariance,
    world_spread,
)
from plugins.calibration.handeye import (
    CLOSED_FORM_METHODS,
    AccuracyTargets,
    NoiseModel,
    calibrate_hand_eye,
    calibrate_robot_world,
    closed_form,
)
from plugins.calibration.handeye.consistency import estimate_unit_scale, mirrored_message
from plugins.calibration.handeye.noise import camera_noise_from_covariances, check_camera_covariances
from plugins.calibration.handeye.problem import Setup, check_setup, frames_of
from plugins.calibration.result import CalibrationResult
from plugins.camera.pinhole import CameraModel

F64 = NDArray[np.float64]
Kind = Literal["hand_eye", "robot_world"]

__all__ = [
    "HandEyeFromImages",
    "ImagePoseMismatchError",
    "calibrate_handeye_images",
    "camera_noise",
    "moved_views",
    "pair_views",
    "view_covariances",
]

MIN_VIEWS = 3
MAX_RMS_PX = 2.0  # above: failed, unless the board's spread is within a robot's pose accuracy (warning)
ACCURACY = AccuracyTargets()
_STD_ADVICE = "add poses with larger rotations about different axes, or reduce the measurement noise"
HOLDOUT_FACTOR = 3.0  # held-out RMS above this times the fit RMS: warning (over-fit or inconsistent views)
# a view's robot-pose correction beyond chi-square(6)'s 1 - p quantile and its RMS through the robot
# RMS_FACTOR times the median view's: an outlier (p this small: a detector's error shared by a view's
# corners has a heavy tail, on rendered images up to 45x chi-square's median)
OUTLIER_P = 1e-9
RMS_FACTOR = 2.0
SCALE_TOL = 0.005  # camera / robot length scale beyond 0.5 %: the board's size is probably wrong


class ImagePoseMismatchError(ValueError):
    """Images and robot poses cannot be paired (different counts)."""


@dataclass(eq=False)
class HandEyeFromImages:
    """Everything the pipeline produced: the result, the views used with their robot and board poses,
    the ML solver's own result (before the pixel refinement) and the refinement."""

    result: CalibrationResult
    views: list[Detection] = field(default_factory=list)
    T_base_tcp: F64 = field(default_factory=lambda: np.zeros((0, 4, 4)))
    board_poses: list[BoardPose] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)
    ml_result: CalibrationResult | None = None
    refinement: Refinement | None = None
    holdout_px: F64 = field(default_factory=lambda: np.zeros(0))
    outlier_views: list[str] = field(default_factory=list)


def pair_views(
    files: Sequence[str | Path], detections: Detections, T_base_tcp: F64
) -> tuple[list[Detection], F64, list[Rejection]]:
    """The views where the board was found with their robot poses (module docstring, step 1)."""
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    if len(files) != len(M):
        raise ImagePoseMismatchError(
            f"{len(files)} image(s) but {len(M)} robot pose(s): images are paired with poses in sorted file "
            "order, one pose per image"
        )
    index = {str(f): k for k, f in enumerate(files)}
    found = sorted(detections.found, key=lambda d: index[d.name])
    return found, M[[index[d.name] for d in found]], list(detections.rejected)


def camera_noise(poses: Sequence[BoardPose]) -> NoiseModel:
    """A shared per-axis noise model from the board poses' covariances (the median variance per axis):
    the robot's prior, and the camera's for a solver that cannot take each view's own (step 4 passes
    them, :func:`view_covariances`)."""
    return camera_noise_from_covariances(np.stack([p.covariance for p in poses]))


def view_covariances(poses: Sequence[BoardPose], notes: list[str]) -> F64 | None:
    """Each view's board-pose covariance ``(n, 6, 6)`` for the solver (module docstring, step 4); None,
    with a note, when one of them is no covariance (not positive definite: the shared median is used)."""
    cov = np.stack([p.covariance for p in poses])
    try:
        return check_camera_covariances(cov, names=[Path(p.name).name for p in poses])
    except ValueError as exc:
        notes.append(f"board-pose covariances not used per view ({exc}); their median per axis is")
        return None


def moved_views(d2: F64, view_rms_px: F64, p: float = OUTLIER_P) -> NDArray[np.bool_]:
    """Views whose corners do not fit through their robot poses like the others (the board moved, or
    a robot pose is not its image's): the whitened square ``d2`` of the view's robot-pose correction
    (6 dof) beyond chi-square's ``1 - p`` quantile, scaled so that the median view is chi-square's
    median (an outlier inflates the noise estimate the corrections share), and the view's RMS
    through its robot pose (the exact-robot fit) above ``RMS_FACTOR`` times the median view's."""
    d2, rms = np.asarray(d2, float), np.asarray(view_rms_px, float)
    if len(d2) < 2 * MIN_VIEWS:
        return np.zeros(len(d2), dtype=bool)
    scale = max(float(np.median(d2)) / chi2.median(6), 1e-12)
    flagged = (d2 > scale * chi2.ppf(1.0 - p, 6)) & (rms > RMS_FACTOR * np.median(rms))
    return flagged if flagged.sum() <= len(d2) // 3 else np.zeros(len(d2), dtype=bool)


def _starts(res: CalibrationResult, x: str, y: str, label: str = "pose solver") -> list[tuple[str, F64, F64]]:
    if x not in res.estimate or y not in res.estimate:
        return []
    return [(label, np.asarray(res.estimate[x], float), np.asarray(res.estimate[y], float))]


def _failed(kind: Kind, reasons: list[str], advice: list[str], rejected: list[Rejection]) -> HandEyeFromImages:
    res = CalibrationResult(kind=kind, verdict="failed", reasons=reasons, advice=advice, method="hand-eye from images")
    return HandEyeFromImages(res, rejected=rejected)


def _param_names(x: str, y: str, camera: CameraModel, intrinsics: bool) -> list[str]:
    comps = ("tx", "ty", "tz", "rx", "ry", "rz")
    names = [f"{x}.{c}" for c in comps] + [f"{y}.{c}" for c in comps]
    if intrinsics:
        names += ["fx_px", "fy_px", "cx_px", "cy_px"] + [f"distortion.{c}" for c in camera.coefficient_names]
    return names


class _PoseSolve(NamedTuple):
    """Step 4's outcome: the ML solver's result, the starts of the pixel refinement ``(label, X, Y)``
    and whether the camera's length scale is off (a wrong square size)."""

    ml: CalibrationResult
    starts: list[tuple[str, F64, F64]]
    wrong_scale: bool


class _PixelFit(NamedTuple):
    """Steps 5-6: the pixel refinement through the robot poses as given from the best start, the same
    with every robot pose corrected (its estimated robot noise beside it), the start and X it began from."""

    exact: Refinement
    noisy: Refinement
    robot_noise: RobotNoise
    start: str
    n_starts: int
    X0: F64


class _Figures(NamedTuple):
    """Step 7's figures of the estimate reported."""

    covariance: F64
    held: F64  # per view: leave-one-view-out RMS (px), NaN when not computed
    held_rms: float
    spread_t: float  # RMS spread of the board's world pose over the views (m, rad)
    spread_r: float
    std_t: float  # 1 sigma of X (m, rad)
    std_r: float


def _solve_poses(kind: Kind, setup: Setup, M: F64, B: F64, poses: list[BoardPose], notes: list[str]) -> _PoseSolve:
    """Step 4: vgr's ML solver on the pose pairs, each view's camera noise its board pose's covariance
    (a common factor of them estimated); a camera length scale off 1 is added to ``notes`` as a wrong
    square size. A result not usable although solved adds the declared-noise solution and the closed
    forms as starts."""
    frames = frames_of(setup)
    solve = calibrate_robot_world if kind == "robot_world" else calibrate_hand_eye
    cov = view_covariances(poses, notes)
    ml = solve(M, B, setup=setup, noise=camera_noise(poses), estimate_noise=True, camera_covariances=cov)
    scale = ml.metrics.get("unit_scale_robot_per_camera")
    wrong_scale = scale is not None and abs(scale - 1.0) > max(5.0 * ml.metrics.get("unit_scale_std", 0.0), SCALE_TOL)
    if wrong_scale:
        notes.append(
            f"square size? the robot moved {scale:.4f}x the distances the camera saw: with the intrinsics right, "
            f"the board's squares are {scale:.4f}x the size given (or the robot poses are not in metres)"
        )
    starts = _starts(ml, frames.x_name, frames.y_name)
    if not ml.usable and starts:  # solved but not trusted: try the declared noise and the closed forms too
        ml_declared = solve(M, B, setup=setup, noise=camera_noise(poses), estimate_noise=False, camera_covariances=cov)
        starts += _starts(ml_declared, frames.x_name, frames.y_name, "pose solver, noise declared")
        starts += [(f"closed form {m}", *closed_form(setup, M, B, m)) for m in CLOSED_FORM_METHODS]
    return _PoseSolve(ml, starts, wrong_scale)


def _refine_pixels(
    setup: Setup,
    M: F64,
    views: list[Detection],
    camera: CameraModel,
    starts: list[tuple[str, F64, F64]],
    refine_intrinsics: bool,
) -> _PixelFit:
    """Steps 5-6: the pixel refinement from every finite start, the one whose corners fit best kept;
    from it, the same corners with every robot pose corrected under a prior: the corner and robot
    noise (variance components), each view's correction (outliers) and, if asked, the estimate."""
    refs = [
        (label, refine_reprojection(setup, M, views, camera, X0, Y0, refine_intrinsics=refine_intrinsics))
        for label, X0, Y0 in starts
        if np.all(np.isfinite(X0)) and np.all(np.isfinite(Y0))
    ]
    start, ref = min(refs, key=lambda lr: lr[1].rms_px)
    X0 = next(x for label, x, _ in starts if label == start)
    noisy = refine_reprojection(
        setup, M, views, ref.camera, ref.X, ref.Y, refine_intrinsics=refine_intrinsics, robot_noise=ESTIMATE
    )
    assert noisy.robot_noise is not None
    return _PixelFit(ref, noisy, noisy.robot_noise, start, len(refs), X0)


def _views_to_leave_out(
    pixel: _PixelFit, n_views: int, left_out: Sequence[str], check_outliers: bool
) -> NDArray[np.bool_] | None:
    """Step 6 (b): the views :func:`moved_views` flags, when there are any and, with those left out
    before, they are at most a third of the views; else None."""
    flagged = (
        moved_views(pixel.noisy.robot_d2, pixel.exact.view_rms_px) if check_outliers else np.zeros(n_views, dtype=bool)
    )
    n_flagged = int(flagged.sum())
    if n_flagged and len(left_out) + n_flagged <= (n_views + len(left_out)) // 3:
        return flagged
    return None


def _figures(
    setup: Setup,
    M: F64,
    B: F64,
    views: list[Detection],
    ref: Refinement,
    pixel: _PixelFit,
    model_robot_noise: bool,
    holdout: bool,
) -> _Figures:
    """Step 7's figures of the estimate ``ref``: leave-one-view-out RMS (refits from ``ref``, the robot
    noise fixed at its estimate when modelled), world-pose spread, the covariance (step 6 (a) or,
    modelling the robot noise, ``ref``'s own) and X's 1 sigma."""
    cam = ref.camera
    noisy = pixel.noisy
    fixed_noise = pixel.robot_noise if model_robot_noise else None

    def fit(train: NDArray[np.int64]) -> tuple[F64, F64]:
        r = refine_reprojection(
            setup, M[train], [views[i] for i in train], cam, ref.X, ref.Y, robot_noise=fixed_noise,
            sigma_px=noisy.sigma_px,
        )  # fmt: skip
        return r.X, r.Y

    held = holdout_rms(setup, M, views, cam, fit) if holdout and len(views) > MIN_VIEWS else np.full(len(views), np.nan)
    spread_t, spread_r, _ = world_spread(setup, M, B, ref.X)
    covariance = (
        ref.covariance
        if model_robot_noise
        else robot_aware_covariance(setup, M, views, ref, noisy.sigma_px, pixel.robot_noise)
    )
    sd = np.sqrt(np.clip(np.diag(covariance)[:6], 0.0, None))
    std_t, std_r = float(np.linalg.norm(sd[:3])), float(np.linalg.norm(sd[3:]))
    held_rms = float(np.sqrt(np.nanmean(held**2))) if np.any(np.isfinite(held)) else float("nan")
    return _Figures(covariance, held, held_rms, spread_t, spread_r, std_t, std_r)


def _judge(
    ml: CalibrationResult,
    notes: list[str],
    left_out: Sequence[str],
    pixel: _PixelFit,
    ref: Refinement,
    fig: _Figures,
    x_name: str,
) -> tuple[Any, list[str], list[str]]:
    """Step 7's verdict, reasons and advice: the pose solver's (its uncertainty and outlier checks
    replaced by the pixel refinement's: a pose pair the pose solver down-weights is judged again by
    how its corners fit, step 6 (b)), the views left out, then the estimate ``ref``'s uncertainty,
    convergence, reprojection RMS and held-out RMS."""
    ml_reasons = [r for r in ml.reasons if "uncertainty" not in r and " outlier sample(s) " not in r]
    if not ml.usable:
        ml_reasons = [
            f"the pose solver alone gave verdict {ml.verdict} ({'; '.join(ml_reasons[-2:])}); the pixel "
            f"refinement started from the best of {pixel.n_starts} starts: {pixel.start}"
        ]
    verdict: Any = "warning" if ml_reasons or left_out else "ok"
    reasons = notes + ml_reasons
    if left_out:
        reasons.insert(
            len(notes),
            f"{len(left_out)} view(s) left out, their corners do not fit through their robot poses like the others' "
            f"do (the board moved, the robot pose is not the image's, or a poor detection): {', '.join(left_out)}",
        )
    advice = [a for a in ml.advice if a != _STD_ADVICE and not a.startswith("inspect the outlier samples")]
    std_t, std_r = fig.std_t, fig.std_r
    over = []
    if std_t > ACCURACY.max_std_trans_m:
        over.append(
            f"translation {std_t * 1e3:.3f} mm (1 sigma) exceeds the target {ACCURACY.max_std_trans_m * 1e3:.2f} mm"
        )
    if std_r > ACCURACY.max_std_rot_rad:
        over.append(
            f"rotation {np.degrees(std_r):.4f} deg (1 sigma) exceeds the target "
            f"{np.degrees(ACCURACY.max_std_rot_rad):.3f} deg"
        )
    if over:
        verdict = "warning"
        reasons.append(f"{x_name} uncertainty: " + "; ".join(over))
        advice.append(_STD_ADVICE)
    if not ref.converged:
        verdict = "warning"
        reasons.append("the pixel refinement stopped before converging")
    if ref.rms_px > MAX_RMS_PX:
        spread = f"{fig.spread_t * 1e3:.2f} mm / {np.degrees(fig.spread_r):.3f} deg RMS"
        if fig.spread_t <= ACCURACY.max_robot_noise_trans_m and fig.spread_r <= ACCURACY.max_robot_noise_rot_rad:
            # as far as a robot's own pose error can take it: the robot limits the result, the data are not wrong
            verdict = "failed" if verdict == "failed" else "warning"
            reasons.append(
                f"the corners reproject at {ref.rms_px:.2f} px RMS through the robot poses, and the board's pose "
                f"predicted from each view spreads by {spread}: within what the robot's own pose accuracy gives "
                f"(a robot's limit: robot {np.degrees(ACCURACY.max_robot_noise_rot_rad):.3g} deg / "
                f"{ACCURACY.max_robot_noise_trans_m * 1e3:.3g} mm), so it limits this calibration"
            )
            advice.append(
                "the robot's pose accuracy is the floor here: calibrate its kinematics (vgr calibrate kinematics), "
                "or model its pose noise (model_robot_noise)"
            )
        else:
            verdict = "failed"
            reasons.append(
                f"the corners' reprojection RMS is {ref.rms_px:.2f} px through the robot poses and the board's pose "
                f"predicted from each view spreads by {spread}, more than any robot's pose error: the board moved, "
                "the robot poses are not the images' (order?), or the set-up is wrong"
            )
    held_rms = fig.held_rms
    if np.isfinite(held_rms) and held_rms > HOLDOUT_FACTOR * ref.rms_px and verdict == "ok":
        verdict = "warning"
        reasons.append(f"held-out views reproject at {held_rms:.2f} px, {held_rms / ref.rms_px:.1f}x the fit")
    return verdict, reasons, advice


def _metrics(
    views: list[Detection],
    rejected: list[Rejection],
    poses: list[BoardPose],
    ml: CalibrationResult,
    ref: Refinement,
    pixel: _PixelFit,
    fig: _Figures,
    left_out: Sequence[str],
) -> dict[str, float]:
    """Step 7's figures as the result's metrics, with the pose solver's chain spread and scale."""
    metrics: dict[str, float] = {
        "n_images": float(len(views) + len(rejected)),
        "n_views": float(len(views)),
        "n_rejected": float(len(rejected)),
        "rms_px": ref.rms_px,
        "sigma_px": ref.sigma_px,
        "corner_sigma_px": pixel.noisy.sigma_px,  # per coordinate, with the robot poses corrected
        "robot_sigma_trans_m": pixel.robot_noise.trans_m,  # per axis, estimated from the corners
        "robot_sigma_rot_rad": pixel.robot_noise.rot_rad,
        "holdout_rms_px": fig.held_rms,
        "world_spread_trans_rms_m": fig.spread_t,
        "world_spread_rot_rms_rad": fig.spread_r,
        "board_pose_rms_px": float(np.sqrt(np.mean([p.rms_px**2 for p in poses]))),
        "nfev": float(ref.nfev),
        "covariance_dof": float(ref.dof),  # the covariance rests on sigma_px estimated from the residuals
        "std_x_trans_m": fig.std_t,
        "std_x_rot_rad": fig.std_r,
    }
    for key in ("chain_spread_trans_rms_m", "chain_spread_rot_rms_rad", "unit_scale_robot_per_camera"):
        if key in ml.metrics:
            metrics[f"ml_{key}"] = ml.metrics[key]
    if left_out:
        metrics["n_outlier_views"] = float(len(left_out))
    return metrics


def _estimate(
    setup: Setup, views: list[Detection], ref: Refinement, X0: F64, left_out: Sequence[str]
) -> dict[str, Any]:
    """The result's estimate: X and Y of ``ref``, the set-up, the camera, the images used, the start
    ``X0`` of the pixel refinement and the outlier views left out."""
    frames = frames_of(setup)
    estimate: dict[str, Any] = {
        frames.x_name: ref.X,
        frames.y_name: ref.Y,
        "setup": setup,
        "camera": ref.camera.to_dict(),
        "sample_labels": [Path(v.name).name for v in views],
        f"initial_{frames.x_name}": X0,
    }
    if left_out:
        estimate["outlier_views"] = list(left_out)
    return estimate


def calibrate_handeye_images(
    views: Sequence[Detection],
    T_base_tcp: F64,
    camera: CameraModel,
    *,
    kind: Kind = "hand_eye",
    setup: Setup = "eye_in_hand",
    refine_intrinsics: bool = False,
    rejected: Sequence[Rejection] = (),
    holdout: bool = True,
    sigma_px: float | None = None,
    model_robot_noise: bool = False,
    check_outliers: bool = True,
    left_out: Sequence[str] = (),
) -> HandEyeFromImages:
    """Hand-eye from paired views (steps 3-6 of the module docstring; :func:`pair_views` gives the input)."""
    setup = check_setup(setup)
    frames = frames_of(setup)
    views = list(views)
    rejected = list(rejected)
    M = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
    if len(views) != len(M):
        raise ImagePoseMismatchError(f"{len(views)} view(s) but {len(M)} robot pose(s)")
    notes = [f"{Path(r.name).name}: {r.reason} (its robot pose dropped)" for r in rejected]
    if len(views) < MIN_VIEWS:
        return _failed(
            kind,
            [*notes, f"the board was found in {len(views)} image(s); hand-eye needs at least {MIN_VIEWS} (10-20 "
             "recommended)"],
            ["check the board spec and that the board is in view"], rejected,
        )  # fmt: skip
    if sigma_px is None:
        rms = camera.extra.get("rms_px")
        sigma_px = float(rms) / np.sqrt(2.0) if rms else None  # RMS distance -> per coordinate
    poses = [board_pose(v, camera, sigma_px=sigma_px) for v in views]
    B = np.stack([p.T_cam_target for p in poses])
    mirrored = mirrored_message(estimate_unit_scale(setup, M, B, signed=True))
    if mirrored is not None:  # (said here with its remedy; the solver would refuse it too)
        return _failed(kind, [*notes, mirrored], ["turn off any image flip in the camera or its driver; check --setup"],
                       rejected)  # fmt: skip
    ml, starts, wrong_scale = _solve_poses(kind, setup, M, B, poses, notes)
    if wrong_scale or not starts:
        ml.reasons = notes + ml.reasons
        if ml.verdict in ("ok", "warning"):
            ml.verdict = "failed"
        return HandEyeFromImages(ml, views, M, poses, rejected, ml)
    pixel = _refine_pixels(setup, M, views, camera, starts, refine_intrinsics)
    flagged = _views_to_leave_out(pixel, len(views), left_out, check_outliers)
    if flagged is not None:
        keep = np.flatnonzero(~flagged)  # left out, and the rest checked again (an outlier hides others)
        return calibrate_handeye_images(
            [views[i] for i in keep], M[keep], camera, kind=kind, setup=setup, refine_intrinsics=refine_intrinsics,
            rejected=rejected, holdout=holdout, sigma_px=sigma_px, model_robot_noise=model_robot_noise,
            left_out=sorted([*left_out, *(Path(views[i].name).name for i in np.flatnonzero(flagged))]),
        )  # fmt: skip
    ref = pixel.noisy if model_robot_noise else pixel.exact
    fig = _figures(setup, M, B, views, ref, pixel, model_robot_noise, holdout)
    verdict, reasons, advice = _judge(ml, notes, left_out, pixel, ref, fig, frames.x_name)
    result = CalibrationResult(
        kind=kind,
        verdict=verdict,
        estimate=_estimate(setup, views, ref, pixel.X0, left_out),
        param_names=_param_names(frames.x_name, frames.y_name, ref.camera, ref.intrinsics_refined),
        covariance=fig.covariance,
        residuals=np.column_stack([ref.view_rms_px, ref.view_max_px, fig.held]),
        residual_names=["rms_px", "max_px", "holdout_rms_px"],
        outliers=np.zeros(len(views), dtype=bool),
        reasons=reasons,
        advice=advice,
        metrics=_metrics(views, rejected, poses, ml, ref, pixel, fig, left_out),
        method=f"board poses -> {ml.method} -> reprojection refinement over {frames.x_name}, {frames.y_name}"
        + (" and the intrinsics" if ref.intrinsics_refined else ""),
        iterations=ref.nfev,
    )
    return HandEyeFromImages(result, views, M, poses, rejected, ml, ref, fig.held, list(left_out))
