"""Hand-eye (AX=XB) and robot-world (AX=ZB) calibration: checks, initialisation, ML, verdict.

Pipeline of :func:`calibrate_hand_eye` / :func:`calibrate_robot_world`:

1. ``validation`` - NaN, shapes, rigidity, duplicates, millimetres (raises ``HandEyeInputError``).
2. ``degeneracy`` - motion set analysed BEFORE solving; a degenerate set returns verdict
   ``degenerate`` with the reasons and the poses to add, and no estimate.
3. ``consistency`` - a given set-up the rotation axes clearly reject, or inverted poses (verdict
   ``failed``), mixed units (error).
   ``setup="auto"`` (the default): steps 2-6 run for both set-ups and ``setup_choice`` takes the
   one the data make likelier (Vuong's test), or refuses (``degenerate``) when they cannot tell.
4. ``consensus`` (least median of squares over pose triples) finds gross outliers; closed forms
   (``closed_form``; all of them for ``init="auto"``, the one with the smallest median pose-chain
   cost wins) run on the consensus set.
5. ``ml`` - maximum likelihood on SE(3) with both noise models, robust loss, outlier flags,
   optional noise estimation, covariance. ``camera_covariances`` (each sample's own camera noise,
   ``noise``) replace the shared camera noise throughout: the ML's whitening, its outlier flags, the
   consensus' cost scale and the set-up test's likelihood; with the noise estimated, one common
   factor of them is (their shape and per-sample scale kept).
6. ``assemble`` - covariance scaling, pose-chain spread, residual table, metrics and verdict.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import Literal, TypedDict, Unpack

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import angle_between
from plugins.calibration.handeye.assemble import RESIDUAL_NAMES, AccuracyTargets, CovarianceScale, assemble_result
from plugins.calibration.handeye.closed_form import CLOSED_FORM_METHODS, closed_form
from plugins.calibration.handeye.consensus import lmeds_consensus, pose_chain_cost
from plugins.calibration.handeye.consistency import check_setup_consistency, estimate_unit_scale, mirrored_message
from plugins.calibration.handeye.degeneracy import MotionThresholds, analyse_motions
from plugins.calibration.handeye.free_scale import SolvedFit, scaled, scaled_covariances, solve_free_scale
from plugins.calibration.handeye.ml import Loss, MLOptions, refine_ml
from plugins.calibration.handeye.noise import DEFAULT_PRIOR, NoiseModel, check_camera_covariances
from plugins.calibration.handeye.problem import SETUPS, Setup, check_setup, frames_of
from plugins.calibration.handeye.setup_choice import SETUP_TEST_LEVEL, SetupCandidate, choose_setup
from plugins.calibration.handeye.validation import HandEyeInputError, ValidatedSamples, validate_samples
from plugins.calibration.result import CalibrationResult

F64 = NDArray[np.float64]
SetupOrAuto = Setup | Literal["auto"]
CameraScale = Literal["fixed", "free"]

__all__ = [
    "RESIDUAL_NAMES",
    "AccuracyTargets",
    "SetupOrAuto",
    "SolverOptions",
    "calibrate_hand_eye",
    "calibrate_robot_world",
]


def _initialise(
    setup: Setup, M: F64, B: F64, methods: Sequence[str], noise: NoiseModel
) -> tuple[str, F64, F64, dict[str, tuple[F64, F64]]]:
    cands: dict[str, tuple[F64, F64]] = {}
    for m in methods:
        X, Y = closed_form(setup, M, B, m)
        if np.all(np.isfinite(X)) and np.all(np.isfinite(Y)):
            cands[m] = (X, Y)
    if not cands:  # cannot happen with validated input; kept so that NaN never reaches the ML
        raise FloatingPointError("every closed-form initialiser returned non-finite values")
    best = min(cands, key=lambda k: float(np.median(pose_chain_cost(setup, M, B, *cands[k], noise))))
    return best, *cands[best], cands


@dataclass(frozen=True)
class _Run:
    """What every set-up's solve shares: the options of one calibration."""

    kind: str
    init: str
    noise: NoiseModel | None
    estimate_noise: bool
    loss: Loss
    covariance_scale: CovarianceScale
    motion_thresholds: MotionThresholds | None
    accuracy: AccuracyTargets
    seed: int
    camera_covariances: F64 | None = None  # (n, 6, 6) of the validated samples, or None: the shared noise

    def prior(self) -> NoiseModel:
        """The noise the ML starts from: declared or DEFAULT_PRIOR, the camera's per sample when given."""
        noise = self.noise if self.noise is not None else DEFAULT_PRIOR
        return noise.with_camera_covariances(self.camera_covariances) if self.camera_covariances is not None else noise


def _check_units(setup: Setup, M: F64, B: F64) -> None:
    """Raise HandEyeInputError when robot and camera lengths differ by a unit factor (``consistency``)."""
    unit = estimate_unit_scale(setup, M, B, signed=True)
    if unit is None:
        return
    mirrored = mirrored_message(unit)
    if mirrored is not None:
        raise HandEyeInputError(mirrored)
    scale, scale_sd = unit
    if not 0.5 <= scale <= 2.0 and abs(scale - 1.0) > 5.0 * scale_sd:
        raise HandEyeInputError(
            f"mixed length units: robot translations = {scale:.4g} x camera translations. " + _unit_hint(scale)
        )


def _unit_hint(scale: float) -> str:
    """What a scale between robot and camera lengths suggests (``_check_units``)."""
    for factor, unit in ((1e-3, "millimetres"), (1e-2, "centimetres"), (0.0254, "inches")):
        for side, s in (("camera", scale), ("robot", 1.0 / scale)):
            if abs(np.log(s / factor)) < 0.1:
                return f"The {side} poses look like {unit}: convert both to metres"
    return (
        "No unit gives that factor: if the camera's translations are in an unknown unit (a monocular "
        "or visual-odometry camera), solve the scale with scale='free' (vgr calibrate ... --scale free)"
    )


@dataclass
class _Checks:
    """What the checks before solving hand on to the result: the verdict so far, reasons, advice, metrics."""

    verdict: str
    reasons: list[str]
    advice: list[str]
    metrics: dict[str, float]


@dataclass(frozen=True)
class _Start:
    """The initial estimate (step 4): the closed form that won, its X and Y, every finite closed form's
    X and Y, and the samples' starting weights (0 for the consensus' outliers)."""

    method: str
    X0: F64
    Y0: F64
    candidates: dict[str, tuple[F64, F64]]
    weights: F64


def _analyse_motion(run: _Run, setup: Setup, data: ValidatedSamples) -> _Checks | CalibrationResult:
    """Step 2 (``degeneracy``): the motion metrics, reasons and advice, or the ``degenerate`` result
    (not solved)."""
    reasons = list(data.warnings)
    advice: list[str] = []
    verdict = "warning" if reasons else "ok"
    motion = analyse_motions(setup, data.T_base_tcp, data.T_cam_target, run.motion_thresholds)
    metrics: dict[str, float] = dict(motion.metrics)
    metrics["n_samples_given"] = float(data.n_given)
    if motion.verdict == "degenerate":
        return CalibrationResult(
            kind=run.kind,
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
    return _Checks(verdict, reasons, advice, metrics)


def _check_consistency(
    run: _Run, setup: Setup, data: ValidatedSamples, checks: _Checks, *, given: bool
) -> CalibrationResult | None:
    """Step 3 (``consistency``): the rotation axes' misfit of either set-up into the metrics; for a
    given set-up, the ``failed`` result when they reject it, and the unit check (raises)."""
    M, B = data.T_base_tcp, data.T_cam_target
    sc = check_setup_consistency(setup, M, B)
    for (s, _), v in sc.mismatch.items():
        checks.metrics[f"axis_misfit_{s}_rad"] = v
    if given and sc.wrong:
        return CalibrationResult(
            kind=run.kind,
            verdict="failed",
            reasons=[*checks.reasons, sc.message],
            advice=[
                "check the set-up (eye_in_hand: camera on the flange; eye_to_hand: camera fixed) and that "
                "robot poses are T_base_tcp and camera poses T_cam_target; the data fit "
                f"setup={sc.best[0]!r} as given (or leave the set-up out to have it found from the data)"
            ],
            metrics=checks.metrics,
            method="consistency check (not solved)",
        )
    if given:
        _check_units(setup, M, B)
    return None


def _initial_estimate(
    run: _Run, setup: Setup, data: ValidatedSamples, noise0: NoiseModel, checks: _Checks
) -> _Start | CalibrationResult:
    """Step 4: the closed forms; when the pose chains look spoilt by outliers, again on the LMedS
    consensus set (``consensus``), whose outliers start the ML at weight 0. The closed forms'
    spread goes into the metrics; no finite closed form is a ``failed`` result."""
    M, B = data.T_base_tcp, data.T_cam_target
    metrics = checks.metrics
    methods = list(CLOSED_FORM_METHODS) if run.init == "auto" else [run.init]
    weights0 = np.ones(data.n)
    try:
        best, X0, Y0, cands = _initialise(setup, M, B, methods, noise0)
    except FloatingPointError as exc:
        return CalibrationResult(kind=run.kind, verdict="failed", reasons=[*checks.reasons, str(exc)], metrics=metrics)
    cost = pose_chain_cost(setup, M, B, X0, Y0, noise0)
    # suspicious samples, or chains far beyond the noise (a start spoilt by many outliers)
    if np.max(cost) > 3.0 * np.median(cost) or np.median(cost) > 10.0:
        consensus = lmeds_consensus(setup, M, B, noise0, seed=run.seed)
        if consensus is not None and 3 <= np.count_nonzero(~consensus.outliers) < data.n:
            keep = ~consensus.outliers
            weights0 = keep.astype(float)
            metrics["consensus_outliers"] = float(np.count_nonzero(consensus.outliers))
            best, X0, Y0, cands = _initialise(setup, M[keep], B[keep], methods, noise0.take(keep))
    if len(cands) > 1:
        Xs = [c[0] for c in cands.values()]
        metrics["closed_form_spread_trans_m"] = max(float(np.linalg.norm(a[:3, 3] - b[:3, 3])) for a in Xs for b in Xs)
        metrics["closed_form_spread_rot_rad"] = max(angle_between(a[:3, :3], b[:3, :3]) for a in Xs for b in Xs)
    return _Start(best, X0, Y0, cands, weights0)


def _solve(run: _Run, setup: Setup, data: ValidatedSamples, *, given: bool) -> SetupCandidate:
    """Motion analysis, consistency, closed forms and ML for one set-up.

    ``given``: the caller stated the set-up, so a reading the rotation axes clearly reject is
    ``failed`` and mixed units raise here; when the set-up is being found from the data, both
    readings are solved and ``setup_choice`` decides (the unit test has run before).
    """
    frames = frames_of(setup)
    checks = _analyse_motion(run, setup, data)
    if isinstance(checks, CalibrationResult):
        return SetupCandidate(setup, checks, None)
    inconsistent = _check_consistency(run, setup, data, checks, given=given)
    if inconsistent is not None:
        return SetupCandidate(setup, inconsistent, None)
    noise0 = run.prior()
    start = _initial_estimate(run, setup, data, noise0, checks)
    if isinstance(start, CalibrationResult):
        return SetupCandidate(setup, start, None)

    M, B = data.T_base_tcp, data.T_cam_target
    fit = refine_ml(
        setup,
        M,
        B,
        start.X0,
        start.Y0,
        noise0,
        options=MLOptions(loss=run.loss, estimate_noise=run.estimate_noise),
        initial_weights=start.weights,
    )
    # the label names the initialiser that was used: for init="auto" the winner of the closed forms
    n_cands = len(start.candidates)
    init_label = (
        f"{start.method} (best of {n_cands} closed forms)" if run.init == "auto" and n_cands > 1 else start.method
    )
    res = assemble_result(
        run.kind, setup, frames.x_name, frames.y_name, data.index, data.labels, M, B, fit, init_label, run.loss,
        run.estimate_noise, run.covariance_scale, run.accuracy, checks.verdict, checks.reasons, checks.advice,
        checks.metrics,
    )  # fmt: skip
    return SetupCandidate(setup, res, fit)


def _calibrate(
    kind: str,
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    init: str,
    setup: SetupOrAuto = "auto",
    noise: NoiseModel | None = None,
    estimate_noise: bool | None = None,
    loss: Loss = "huber",
    covariance_scale: CovarianceScale = "auto",
    motion_thresholds: MotionThresholds | None = None,
    accuracy: AccuracyTargets | None = None,
    sample_ids: Sequence[str] | None = None,
    setup_test_level: float = SETUP_TEST_LEVEL,
    seed: int = 0,
    scale: CameraScale = "fixed",
    camera_covariances: ArrayLike | None = None,
) -> CalibrationResult:
    if scale not in ("fixed", "free"):
        raise ValueError(f"scale must be 'fixed' or 'free', got {scale!r}")
    if noise is not None and noise.camera_covariances is not None:
        if camera_covariances is not None:
            raise ValueError("camera covariances given twice: in noise and as camera_covariances")
        camera_covariances, noise = noise.camera_covariances, noise.with_camera_covariances(None)
    solve = partial(
        _calibrate_fit, kind, T_base_tcp, init=init, setup=setup, noise=noise, estimate_noise=estimate_noise,
        loss=loss, covariance_scale=covariance_scale, motion_thresholds=motion_thresholds, accuracy=accuracy,
        sample_ids=sample_ids, setup_test_level=setup_test_level, seed=seed,
    )  # fmt: skip
    if scale == "free":
        start = "eye_in_hand" if setup == "auto" else check_setup(setup)  # (the screw invariant is either's)

        def at_scale(k: float) -> tuple[CalibrationResult, SolvedFit | None]:
            B_k = scaled(np.asarray(T_cam_target, dtype=float), k)
            return solve(B_k, camera_covariances=scaled_covariances(camera_covariances, k))

        return solve_free_scale(at_scale, kind, T_base_tcp, T_cam_target, start, accuracy or AccuracyTargets())
    return solve(T_cam_target, camera_covariances=camera_covariances)[0]


def _calibrate_fit(
    kind: str,
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    init: str,
    setup: SetupOrAuto,
    noise: NoiseModel | None,
    estimate_noise: bool | None,
    loss: Loss,
    covariance_scale: CovarianceScale,
    motion_thresholds: MotionThresholds | None,
    accuracy: AccuracyTargets | None,
    sample_ids: Sequence[str] | None,
    setup_test_level: float,
    seed: int,
    camera_covariances: ArrayLike | None,
) -> tuple[CalibrationResult, SolvedFit | None]:
    """One calibration at the camera's scale as given: the result, and the ML fit behind it (with
    its set-up) when there is one."""
    if setup != "auto":
        setup = check_setup(setup)
    if init != "auto" and init not in CLOSED_FORM_METHODS:
        raise ValueError(f"init must be 'auto' or one of {list(CLOSED_FORM_METHODS)}, got {init!r}")
    if covariance_scale not in ("auto", "a_priori", "a_posteriori"):
        raise ValueError(f"covariance_scale must be auto, a_priori or a_posteriori, got {covariance_scale!r}")
    if not 0.0 < setup_test_level < 1.0:
        raise ValueError(f"setup_test_level must be in (0, 1), got {setup_test_level!r}")
    data = validate_samples(T_base_tcp, T_cam_target, ids=sample_ids)
    cov = None if camera_covariances is None else _checked_covariances(camera_covariances, data, sample_ids)
    run = _Run(
        kind=kind,
        init=init,
        noise=noise,
        estimate_noise=(noise is None) if estimate_noise is None else estimate_noise,
        loss=loss,
        covariance_scale=covariance_scale,
        motion_thresholds=motion_thresholds,
        accuracy=accuracy or AccuracyTargets(),
        seed=seed,
        camera_covariances=cov,
    )
    if setup != "auto":
        cand = _solve(run, setup, data, given=True)
        return cand.result, None if cand.fit is None else SolvedFit(setup, cand.fit, data)
    # the unit test's screw invariant is the same for both readings (inverse and conjugate keep it);
    # as for a given set-up, it runs on motions that are not degenerate (tiny noisy rotations bias it)
    motions = [analyse_motions(s, data.T_base_tcp, data.T_cam_target, motion_thresholds) for s in SETUPS]
    if all(m.verdict != "degenerate" for m in motions):
        _check_units("eye_in_hand", data.T_base_tcp, data.T_cam_target)
    candidates = {s: _solve(run, s, data, given=False) for s in SETUPS}
    result, chosen = choose_setup(
        kind, data.T_base_tcp, data.T_cam_target, candidates, declared=not run.estimate_noise, level=setup_test_level
    )
    fit = None if chosen is None else candidates[chosen].fit
    return result, None if chosen is None or fit is None else SolvedFit(chosen, fit, data)


def _checked_covariances(covariances: ArrayLike, data: ValidatedSamples, ids: Sequence[str] | None) -> F64:
    """The camera covariances of the validated samples (``noise.check_camera_covariances``, in the
    caller's order, then the rows kept); a bad one is a HandEyeInputError naming its sample."""
    names = [str(k) for k in range(data.n_given)] if ids is None else [str(i) for i in ids]
    try:
        cov = check_camera_covariances(covariances, data.n_given, names)
    except ValueError as exc:
        raise HandEyeInputError(str(exc)) from None
    return cov[data.index]


class SolverOptions(TypedDict, total=False):
    """Keyword options of :func:`calibrate_hand_eye` and :func:`calibrate_robot_world` besides ``init``."""

    setup: SetupOrAuto
    noise: NoiseModel | None
    estimate_noise: bool | None
    loss: Loss
    covariance_scale: CovarianceScale
    motion_thresholds: MotionThresholds | None
    accuracy: AccuracyTargets | None
    sample_ids: Sequence[str] | None
    setup_test_level: float
    seed: int
    scale: CameraScale
    camera_covariances: ArrayLike | None


def calibrate_hand_eye(
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    init: str = "auto",
    **options: Unpack[SolverOptions],
) -> CalibrationResult:
    """Hand-eye calibration (AX = XB) from robot poses T_base_tcp and camera observations T_cam_target.

    Args:
        T_base_tcp: robot flange/TCP poses in the base frame, ``(n, 4, 4)`` in metres.
        T_cam_target: calibration target poses seen by the camera, ``(n, 4, 4)`` in metres.
        init: ``"auto"`` (best of all closed forms) or one of ``tsai_lenz``, ``park_martin``,
            ``daniilidis``, ``shah``.
        options (:class:`SolverOptions`, all optional):
            setup: ``"eye_in_hand"`` (estimates ``T_tcp_cam`` and the fixed ``T_base_target``),
                ``"eye_to_hand"`` (estimates ``T_base_cam`` and the target on the flange ``T_tcp_target``)
                or ``"auto"`` (default): both are solved and the likelier taken when the data tell them
                apart (``setup_choice``; the reasons say which and why); when they cannot, the verdict is
                ``degenerate`` and nothing is estimated.
            noise: declared robot / camera noise; ``None`` (default) estimates it from the data.
            estimate_noise: force noise estimation on or off (default: on exactly when ``noise`` is None).
            loss: ``"huber"`` (default), ``"cauchy"`` or ``"linear"`` (plain ML, no down-weighting).
            covariance_scale: ``"auto"`` (default), ``"a_priori"`` or ``"a_posteriori"``; see the
                module docstring.
            motion_thresholds: of the motion analysis before solving (default ``MotionThresholds()``).
            accuracy: the accuracy targets and noise limits of the verdict (default ``AccuracyTargets()``).
            sample_ids: the caller's name of each sample (e.g. the ids of its file), used wherever a
                sample is named (input errors, outliers, ``estimate["sample_labels"]``); default 0, 1, ...
            setup_test_level: two-sided level of the set-up test for ``setup="auto"`` (default 0.001).
            seed: seed of the random choice of pose triples in the outlier consensus (``consensus``), 0.
            scale: ``"fixed"`` (default): camera translations are in metres; ``"free"``: in an unknown
                unit (a monocular or visual-odometry camera), the scale solved with its 1-sigma
                (``free_scale``: ``estimate["camera_scale"]``, metrics ``camera_scale``, ``_sd``).
            camera_covariances: ``(n, 6, 6)``, each sample's own camera covariance of the decoupled
                ``(dt, dphi)`` perturbation in the camera frame, ordered ``(tx, ty, tz, rx, ry, rz)``,
                m^2 / rad^2 / m rad (``noise``; a depth camera's or PnP's error is largest along its line
                of sight and grows with the distance). They replace the camera part of ``noise`` (whose
                robot part is kept); with the noise estimated (``noise=None``), one common factor of
                them is estimated (metric ``noise_camera_covariance_factor``). With ``scale="free"``
                they are in the camera's units, like its translations. Non-finite, non-symmetric or
                non-positive-definite ones raise ``HandEyeInputError`` naming the sample.

    Returns:
        CalibrationResult with estimate ``{x_name, y_name, "setup"}``, 12x12 covariance, per-sample
        residuals (``RESIDUAL_NAMES``), outlier flags, verdict, reasons, advice and metrics.

    Raises:
        HandEyeInputError: unusable input (NaN, shapes, non-rigid poses, millimetres, mixed units).
    """
    return _calibrate("hand_eye", T_base_tcp, T_cam_target, init=init, **options)


def calibrate_robot_world(
    T_base_tcp: Sequence[ArrayLike] | ArrayLike,
    T_cam_target: Sequence[ArrayLike] | ArrayLike,
    *,
    init: str = "shah",
    **options: Unpack[SolverOptions],
) -> CalibrationResult:
    """Robot-world + hand-eye calibration (AX = ZB): X and Z estimated jointly, both reported.

    Same data and arguments as :func:`calibrate_hand_eye`; ``A_i = T_base_tcp_i`` (or its inverse
    for eye-to-hand), ``B_i = T_cam_target_i^-1``, X the hand-eye transform and Z = ``T_base_target``
    (eye-in-hand) or ``T_tcp_target`` (eye-to-hand). Initialised with Shah's Kronecker closed form by
    default; the ML refinement and the result are those of the hand-eye solver.
    """
    return _calibrate("robot_world", T_base_tcp, T_cam_target, init=init, **options)
