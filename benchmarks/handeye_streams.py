"""Hand-eye on hard data: vgr's solver against OpenCV 4's seven methods, simulated eye-in-hand cells.

Ground truth known, seeds fixed (``--seed``); ``--trials`` seeded trials per case (default 30).
vgr is called as an integrator would call it: ``calibrate_hand_eye(M, B, setup="eye_in_hand")``,
the noise estimated from the data (nothing about the truth declared). Peers: OpenCV's five
``calibrateHandEye`` methods (TSAI, PARK, HORAUD, ANDREFF, DANIILIDIS) and its two
``calibrateRobotWorldHandEye`` methods (SHAH, LI), through the wrappers of benchmarks/handeye.py.
Robot noise is 0.01 deg / 0.1 mm, camera noise 0.1 deg / 0.5 mm per axis (decoupled, parent
frame, plugins/calibration/handeye/noise.py) unless a condition says otherwise. Conditions:

1. ``clock_offset`` - two pose streams with their own clocks (``robot_time = camera_time +
   offset``). The robot moves continuously about a pose that shows the camera the target from
   0.5 m: each of the six coordinates (translation, rotation vector) a sum of three sinusoids of
   0.08-0.35 Hz (about 0.5 rad/s and 0.15 m/s RMS; each case records the speeds), robot poses exact
   at 250 Hz for 32 s; the camera at 10, 30 or 60 Hz for 30 s, 10 % of its frames dropped, stamps
   with 1 ms jitter (sd), poses with 0.05 deg / 0.3 mm noise; offsets 0, 20, 50, 100, 200 ms.
   vgr: the path of plugins/calibration/handeye/stream_file.py (``streams.fit_offset``, the camera
   paired with the robot interpolated at its stamps plus the offset, at most
   ``MAX_STREAM_SAMPLES`` pairs evenly spread in time), then the solver. Peers: each camera pose
   paired with the robot pose of the nearest stamp (no offset known), as many pairs as vgr's solver
   gets, evenly spread. Reported: the offset's error (ms), its stated 1-sigma, the RMS of
   error / sigma (near 1 when the sigma is honest) and the fractions of the trials whose error is
   within 1 and 2 sigma (68.3 % and 95.4 % when honest).
2. ``outliers`` - 40 poses of ``simulate.viewing_scene``; 0, 10, 20, 35 or 50 % of the camera poses
   replaced by: ``random_pose`` (a uniformly random rotation, the translation the true one plus
   30 mm sd per axis), ``planar_flip`` (the planar target's PnP ambiguity: the pose's rotation
   turned by twice the angle between the target's normal and its line of sight, about the axis
   perpendicular to both, i.e. the normal reflected about the line of sight; only views tilted by
   5 deg or more are flipped, smaller flips are within the noise) or ``gross_error`` (2-10 mm and
   1-5 deg in random directions on top of the noise). The noise Gaussian or heavy-tailed
   (Student-t, 3 dof, scaled to the same sd). Reported: vgr's false flags (flagged true inliers /
   true inliers, pooled over the trials), missed outliers (unflagged / true outliers), verdicts.
3. ``anisotropic`` - camera noise per axis of the camera frame (z the optical axis): translation
   (0.3, 0.3, 1.0) mm with rotation (0.2, 0.2, 0.05) deg (``low``) and (1.2, 1.2, 4.0) mm with
   (0.3, 0.3, 0.1) deg (``high``); 15 and 60 poses. And ``per-sample covariance given``: each view's
   own noise (``simulate.depth_covariances``: 0.3 mm across its line of sight at 0.5 m growing with
   the distance, 5-10x that along it growing with its square, 0.1 deg tilt / 0.03 deg roll, lateral
   shift and tilt correlated by 0.6), drawn with it; vgr gets the covariances
   (``camera_covariances=``, one common factor of them estimated), the peers cannot use them, and
   vgr without them is recorded beside (``vgr_without_covariances``, the same trials; target: with
   <= without).
4. ``unknown_scale`` - 15 poses, the measured camera translations multiplied by 0.1, 0.5, 2 or 10
   (wrong target size or intrinsics). vgr is run with ``scale="free"`` when its ``SolverOptions``
   has a ``scale`` option (then its ``camera_scale`` metric, metres per camera unit, is compared
   with 1 / s: ``camera_scale_rel_error``), else it is recorded as not supported (error NaN, with
   the reason). What vgr says about such data when called without the option is recorded apart
   (``vgr_without_scale_option``: verdicts, refusals, its ``unit_scale_robot_per_camera`` metric),
   not as its result. The peers get the scaled data as is (none of them estimates a scale).
5. ``poses`` - 3, 5, 8, 15, 50 and 200 poses, no outliers; and weak motion: 5 and 15 poses with
   ``viewing_scene``'s ``max_tilt_deg`` = ``max_roll_deg`` = 3 or 8 deg.

Errors: T_tcp_cam's translation (mm) and rotation (deg) against the truth; per method and case the
median and 95th percentile over the trials, a failure counted as an infinite error (so a method
that fails in half of the trials has no finite median; ``null`` in the JSON). Failures: a vgr
refusal (``HandEyeInputError``, a numerical exception, an offset fit that raises, a result without
an estimate - e.g. verdict ``degenerate``) is data, counted under ``refused``; an estimate with
verdict ``failed`` is scored and counted in the verdicts. OpenCV failures count likewise: an
exception, non-finite output, a rotation part that is no rotation (a reflection), or the identity
its hand-eye methods return after logging "Hand-eye calibration failed!".

Targets (printed PASS/FAIL per condition, stored under ``targets``): per case, vgr's median
translation error <= the best peer's median (where vgr refused the data, passed only when every
peer's median is beyond 10 mm, ``UNUSABLE_MM``: then no method gave a usable result); the clock offset's worst absolute error over the
trials <= 1 ms at 30 Hz (every offset); vgr's false flags <= 1 % on outlier-free data (fraction 0,
both noise kinds).

Usage: ``python benchmarks/handeye_streams.py [--trials 30] [--seed 11] [--quick] [--out PATH]
[--condition NAME ...]``. The full run writes handeye_streams.json, ``--quick`` (3 trials per case
unless ``--trials`` says otherwise) handeye_streams_quick.json, both in benchmarks/results/; a quick
result says ``"quick": true`` and is a smoke test of the script, not a measurement. ``--condition``
runs only the conditions named; their entries (cases, targets) replace those of the result file
already there (same seed, trials and quick mark; the others are kept, and ``partial_runs`` records
the run), or start a new file.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.console import Console
from rich.table import Table
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402  (the comparator)

from benchmarks.bench_results import machine, write_result  # noqa: E402
from benchmarks.handeye import CV_HAND_EYE, CV_ROBOT_WORLD, opencv_hand_eye, opencv_robot_world  # noqa: E402
from engine.transforms import inv, is_rotation, pose_error, retract  # noqa: E402
from plugins.calibration.handeye import HandEyeInputError, PoseNoise, Setup, calibrate_hand_eye  # noqa: E402
from plugins.calibration.handeye import simulate as sim  # noqa: E402
from plugins.calibration.handeye.solver import SolverOptions  # noqa: E402
from plugins.calibration.handeye.stream_file import MAX_STREAM_SAMPLES  # noqa: E402
from plugins.calibration.handeye.streams import PoseStream, angular_speed, fit_offset, paired  # noqa: E402

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]
Solver = Callable[[F64, F64], F64]
Options = dict[str, Any]

SETUP: Setup = "eye_in_hand"
VGR_OPTIONS: Options = {"setup": SETUP}  # the noise estimated from the data
PEERS: dict[str, Solver] = {
    **{k: opencv_hand_eye(v) for k, v in CV_HAND_EYE.items()},
    **{k: opencv_robot_world(v) for k, v in CV_ROBOT_WORLD.items()},
}
METHODS = ("vgr", *PEERS)
SHORT = {m: m.removeprefix("opencv_").removeprefix("rw_") for m in METHODS}
ROBOT_NOISE = PoseNoise.from_deg_mm(0.01, 0.1)
CAMERA_NOISE = PoseNoise.from_deg_mm(0.1, 0.5)
_TRUTH = sim.viewing_scene(np.random.default_rng(0), 1)
X_TRUE, Y_TRUE = _TRUTH.X, _TRUTH.Y  # viewing_scene's eye-in-hand T_tcp_cam and T_base_target

# 1. clock offset
ROBOT_HZ, ROBOT_SPAN_S, CAMERA_SPAN_S = 250.0, (0.0, 32.0), (1.0, 31.0)
CAMERA_HZ = (10.0, 30.0, 60.0)
OFFSETS_MS = (0.0, 20.0, 50.0, 100.0, 200.0)
STAMP_JITTER_S, DROPPED, VIEW_DISTANCE_M = 1e-3, 0.10, 0.5
STREAM_CAMERA_NOISE = PoseNoise.from_deg_mm(0.05, 0.3)
MOTION_AMPLITUDE = np.array([0.09, 0.09, 0.06, 0.21, 0.21, 0.30])  # m (x, y, z), rad (rotation vector)
MOTION_HZ, MOTION_TERMS = (0.08, 0.35), 3
OFFSET_TARGET_MS, OFFSET_TARGET_HZ = 1.0, 30.0
# 2. outliers
OUTLIER_POSES = 40
OUTLIER_FRACTIONS = (0.10, 0.20, 0.35, 0.50)
OUTLIER_KINDS = ("random_pose", "planar_flip", "gross_error")
TAILS = ("gaussian", "student_t3")
RANDOM_POSE_TRANS_SD_M, MIN_FLIP_TILT_DEG = 0.03, 5.0
GROSS_MM, GROSS_DEG = (2.0, 10.0), (1.0, 5.0)
FALSE_FLAG_TARGET = 0.01
# 3.-5.
ANISOTROPIC = {
    "low": PoseNoise.from_deg_mm((0.2, 0.2, 0.05), (0.3, 0.3, 1.0)),
    "high": PoseNoise.from_deg_mm((0.3, 0.3, 0.1), (1.2, 1.2, 4.0)),
}
ANISOTROPIC_POSES = (15, 60)
COVARIANCE_CASE = "per-sample covariance given"
GIVEN = "given"  # vgr option value: the trial's own camera covariances
VGR_WITH_COVARIANCES: Options = {**VGR_OPTIONS, "camera_covariances": GIVEN}
SCALES, SCALE_POSES = (0.1, 0.5, 2.0, 10.0), 15
POSE_COUNTS = (3, 5, 8, 15, 50, 200)
WEAK_MOTION = ((5, 3.0), (5, 8.0), (15, 3.0), (15, 8.0))  # (poses, max tilt = max roll, deg)
SCALE_METRICS = ("unit_scale_robot_per_camera", "camera_scale", "camera_scale_sd")  # vgr's metrics, recorded


def _rng(seed: int, *keys: int) -> np.random.Generator:
    """An independent, reproducible generator for (seed, condition, trial, ...)."""
    return np.random.default_rng([seed, *keys])


def _error(X_est: F64 | None, X: F64) -> tuple[float, float]:
    """Translation (mm) and rotation (deg) error of an estimate of T_tcp_cam; NaN for none, or for
    one that is not a rigid transform (OpenCV returns reflections on some outlier sets)."""
    if X_est is None or not np.all(np.isfinite(X_est)) or not is_rotation(X_est[:3, :3], tol=1e-4):
        return float("nan"), float("nan")
    dt, dr = pose_error(X_est, X)
    return dt * 1e3, float(np.rad2deg(dr))


def _spread(n: int, k: int) -> NDArray[np.intp]:
    """Up to *k* of *n* indices, evenly spread (as stream_file takes its samples)."""
    return np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(int))


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


@dataclass
class Trial:
    """One trial's data: what vgr gets (M, B) and what the peers get (the same unless given), the
    truth, which camera poses are outliers, per-trial figures, and a refusal of vgr's own pairing."""

    M: F64
    B: F64
    X: F64
    outliers: Mask | None = None
    peer_M: F64 | None = None
    peer_B: F64 | None = None
    extra: dict[str, float] = field(default_factory=dict)
    vgr_refusal: str | None = None
    camera_covariances: F64 | None = None  # (n, 6, 6) each camera pose's noise, when the trial has them


@dataclass
class VgrRun:
    """One vgr calibration: T_tcp_cam's errors (NaN without an estimate), the verdict (or
    ``input_error``, ``solver_error``, ``not_run``, ``not_supported``), outlier flags, why it gave
    no estimate, and its metrics."""

    trans_mm: float
    rot_deg: float
    verdict: str
    flags: Mask | None = None
    refusal: str | None = None
    metrics: dict[str, float] = field(default_factory=dict)


@dataclass
class Tally:
    """What the trials of one case add up to."""

    errors: dict[str, list[tuple[float, float]]] = field(default_factory=lambda: {m: [] for m in METHODS})
    verdicts: Counter[str] = field(default_factory=Counter)
    refusals: Counter[str] = field(default_factory=Counter)
    peer_failures: Counter[str] = field(default_factory=Counter)
    flags: Counter[str] = field(default_factory=Counter)  # false, inliers, missed, outliers, trials
    extra: dict[str, list[float]] = field(default_factory=dict)

    def add_vgr(self, run: VgrRun, truth_outliers: Mask | None) -> None:
        self.errors["vgr"].append((run.trans_mm, run.rot_deg))
        self.verdicts[run.verdict] += 1
        if run.refusal is not None:
            self.refusals[run.refusal[:90]] += 1
        if run.flags is not None:
            bad = np.zeros(len(run.flags), bool) if truth_outliers is None else truth_outliers
            self.flags.update(
                false=int(np.sum(run.flags & ~bad)),
                inliers=int(np.sum(~bad)),
                missed=int(np.sum(~run.flags & bad)),
                outliers=int(np.sum(bad)),
                trials=1,
            )
        for key in SCALE_METRICS:  # the camera length scale vgr sees (or solves, scale="free")
            if key in run.metrics:
                self.extra.setdefault(key, []).append(float(run.metrics[key]))


def run_vgr(M: F64, B: F64, X: F64, options: Options) -> VgrRun:
    """vgr's solver on (M, B); an input error, a numerical exception or a result without an
    estimate is a refusal (programming errors are not caught)."""
    try:
        res = calibrate_hand_eye(M, B, **options)
    except HandEyeInputError as exc:
        return VgrRun(float("nan"), float("nan"), "input_error", refusal=f"HandEyeInputError: {exc}")
    except (ArithmeticError, np.linalg.LinAlgError, RuntimeError, ValueError) as exc:  # numerics: a failure
        return VgrRun(float("nan"), float("nan"), "solver_error", refusal=f"{type(exc).__name__}: {exc}")
    X_est = res.estimate.get("T_tcp_cam")
    if X_est is None:
        why = res.reasons[-1] if res.reasons else ""
        return VgrRun(float("nan"), float("nan"), res.verdict, refusal=f"no estimate ({res.verdict}): {why}")
    flags = None if res.outliers is None else np.asarray(res.outliers, bool)
    return VgrRun(*_error(np.asarray(X_est), X), res.verdict, flags, None, dict(res.metrics))


def run_peers(M: F64, B: F64, X: F64) -> dict[str, tuple[float, float]]:
    """Every OpenCV method on (M, B). A failure (NaN): an exception, a result that is not a rigid
    transform, or the identity OpenCV returns after logging "Hand-eye calibration failed!"."""
    out = {}
    for name, solve in PEERS.items():
        try:
            with np.errstate(all="ignore"):
                X_est = solve(M, B)
        except (cv2.error, np.linalg.LinAlgError, ValueError):
            X_est = None
        out[name] = _error(None if X_est is None or np.array_equal(X_est, np.eye(4)) else X_est, X)
    return out


def evaluate(trial: Trial, vgr_options: Options | None, tally: Tally, *, peers: bool = True) -> None:
    """Run vgr (None: not supported, NaN) and the peers on one trial, into *tally*."""
    if trial.vgr_refusal is not None:
        tally.add_vgr(VgrRun(float("nan"), float("nan"), "not_run", refusal=trial.vgr_refusal), None)
    elif vgr_options is None:
        tally.add_vgr(VgrRun(float("nan"), float("nan"), "not_supported"), None)
    else:
        options = vgr_options
        if vgr_options.get("camera_covariances") is GIVEN:
            options = {**vgr_options, "camera_covariances": trial.camera_covariances}
        tally.add_vgr(run_vgr(trial.M, trial.B, trial.X, options), trial.outliers)
    for key, value in trial.extra.items():
        tally.extra.setdefault(key, []).append(value)
    if not peers:
        return
    M = trial.M if trial.peer_M is None else trial.peer_M
    B = trial.B if trial.peer_B is None else trial.peer_B
    for name, err in run_peers(M, B, trial.X).items():
        tally.errors[name].append(err)
        if not np.all(np.isfinite(err)):
            tally.peer_failures[name] += 1


def run_case(make: Callable[[int], Trial], trials: int, vgr_options: Options | None, *, peers: bool = True) -> Tally:
    tally = Tally()
    for k in range(trials):
        evaluate(make(k), vgr_options, tally, peers=peers)
    return tally


# --------------------------------------------------------------------------- summaries


def summarise_errors(errors: list[tuple[float, float]]) -> dict[str, float]:
    """Median and 95th percentile of the translation / rotation errors, failures as +inf."""
    a = np.array(errors, dtype=float).reshape(-1, 2)
    failed = ~np.isfinite(a).all(axis=1)
    b = np.where(failed[:, None], np.inf, a)
    return {
        "n": len(a),
        "n_failed": int(failed.sum()),
        "trans_median_mm": float(np.median(b[:, 0])),
        "trans_p95_mm": float(np.quantile(b[:, 0], 0.95, method="higher")),
        "rot_median_deg": float(np.median(b[:, 1])),
        "rot_p95_deg": float(np.quantile(b[:, 1], 0.95, method="higher")),
    }


def _plain(x: Any) -> Any:
    """Non-finite floats as None (JSON null), through dicts and lists."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    return _num(x) if isinstance(x, float) else x


def case_record(label: str, params: dict[str, Any], tally: Tally) -> dict[str, Any]:
    """A case's entry: parameters, per-method error summaries, vgr's verdicts, refusals and flags."""
    methods = {m: summarise_errors(errs) for m, errs in tally.errors.items() if errs}
    peers = {m: s["trans_median_mm"] for m, s in methods.items() if m != "vgr"}
    best = min(peers, key=lambda m: peers[m]) if peers else None
    f = tally.flags
    rec: dict[str, Any] = {
        "case": label,
        "params": params,
        "methods": methods,
        "best_peer": best,
        "vgr": {
            "verdicts": dict(tally.verdicts),
            "refused": sum(tally.refusals.values()),
            "refusal_reasons": dict(tally.refusals.most_common(3)),
        },
        "peer_failures": dict(tally.peer_failures),
    }
    if f["trials"]:
        rec["vgr"]["false_flag_rate"] = f["false"] / f["inliers"] if f["inliers"] else float("nan")
        rec["vgr"]["missed_outlier_rate"] = f["missed"] / f["outliers"] if f["outliers"] else float("nan")
        rec["vgr"]["flag_counts"] = dict(f)
    for key, values in tally.extra.items():
        v = np.asarray(values, float)
        rec.setdefault("figures", {})[key] = {"median": float(np.median(v)), "max_abs": float(np.max(np.abs(v)))}
    return rec


UNUSABLE_MM = 10.0  # a hand-eye error no cell can work with: refusing such data is the right answer


def beats_peers(condition: str, rec: dict[str, Any]) -> dict[str, Any]:
    """The target: vgr's median translation error <= the best peer's; or, where vgr refused most
    trials (no finite median), every peer's median beyond UNUSABLE_MM (the data cannot give a
    usable calibration: the refusal is right, and it is said so in the target's name)."""
    vgr = rec["methods"]["vgr"]["trans_median_mm"]
    best = rec["best_peer"]
    peer = rec["methods"][best]["trans_median_mm"] if best else float("inf")
    if not np.isfinite(vgr) and rec["vgr"]["refused"] and not peer <= UNUSABLE_MM:
        target = f"vgr refused; best peer ({best}) beyond {UNUSABLE_MM:g} mm"
        return check(condition, rec["case"], target, vgr, peer, True)
    ok = bool(np.isfinite(vgr) and vgr <= peer)
    return check(condition, rec["case"], f"vgr median trans <= best peer ({best})", vgr, peer, ok)


def check(condition: str, case: str, target: str, value: float, limit: float, passed: bool) -> dict[str, Any]:
    return {"condition": condition, "case": case, "target": target, "value": value, "limit": limit, "passed": passed}


# --------------------------------------------------------------------------- 1. clock offset


def robot_motion(rng: np.random.Generator) -> Callable[[F64], F64]:
    """T_base_tcp(t): about the pose that shows the camera the target straight on from
    VIEW_DISTANCE_M, each coordinate (translation, base-frame rotation vector about the flange) a
    sum of MOTION_TERMS sinusoids."""
    B0 = np.eye(4)
    B0[:3, :3] = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()
    B0[:3, 3] = (0.0, 0.0, VIEW_DISTANCE_M)
    M0 = Y_TRUE @ inv(B0) @ inv(X_TRUE)
    freq = rng.uniform(*MOTION_HZ, size=(MOTION_TERMS, 6))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(MOTION_TERMS, 6))
    amp = MOTION_AMPLITUDE / np.sqrt(MOTION_TERMS)

    def flange(t: F64) -> F64:
        w = np.sum(amp * np.sin(2.0 * np.pi * freq * t[:, None, None] + phase), axis=1)
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, :3] = Rotation.from_rotvec(w[:, 3:]).as_matrix() @ M0[:3, :3]
        T[:, :3, 3] = M0[:3, 3] + w[:, :3]
        return T

    return flange


def camera_stream(
    rng: np.random.Generator, flange: Callable[[F64], F64], rate_hz: float, offset_s: float
) -> PoseStream:
    """The camera's stream: frames at *rate_hz*, DROPPED of them lost, poses with noise, stamps
    with jitter on the camera's clock (``robot_time = camera_time + offset_s``)."""
    t_true = np.arange(*CAMERA_SPAN_S, 1.0 / rate_hz)
    t_true = t_true[rng.random(len(t_true)) >= DROPPED]
    B = sim.perturb_poses(inv(X_TRUE) @ inv(flange(t_true)) @ Y_TRUE, STREAM_CAMERA_NOISE, rng)
    stamps = t_true + rng.normal(0.0, STAMP_JITTER_S, len(t_true)) - offset_s
    order = np.argsort(stamps)
    return PoseStream(stamps[order], B[order])


def nearest_pairs(robot: PoseStream, camera: PoseStream) -> tuple[F64, F64]:
    """Each camera pose inside the robot stream with the robot pose of the nearest stamp."""
    s, t = robot.stamps_s, camera.stamps_s
    inside = (t >= s[0]) & (t <= s[-1])
    ti = t[inside]
    k = np.clip(np.searchsorted(s, ti), 1, len(s) - 1)
    k -= (ti - s[k - 1]) < (s[k] - ti)
    return robot.T[k], camera.T[inside]


def clock_trial(seed: int, trial: int, rate_hz: float, offset_s: float) -> Trial:
    """One trial: the motion shared by every case of the trial, the camera frames by every offset."""
    flange = robot_motion(_rng(seed, 1, trial))
    t_robot = np.arange(*ROBOT_SPAN_S, 1.0 / ROBOT_HZ)
    robot = PoseStream(t_robot, flange(t_robot))
    camera = camera_stream(_rng(seed, 1, trial, int(rate_hz)), flange, rate_hz, offset_s)
    speeds = {
        "robot_rms_rad_s": float(np.sqrt(np.mean(angular_speed(robot)[1] ** 2))),
        "robot_rms_m_s": float(np.sqrt(np.mean(np.sum(np.diff(robot.T[:, :3, 3], axis=0) ** 2, axis=1))) * ROBOT_HZ),
    }
    peer_M, peer_B = nearest_pairs(robot, camera)
    try:
        fit = fit_offset(SETUP, robot, camera)
    except ValueError as exc:
        take = _spread(len(peer_M), MAX_STREAM_SAMPLES)
        return Trial(peer_M[take], peer_B[take], X_TRUE, extra=speeds, vgr_refusal=f"fit_offset: {exc}")
    M, B, _ = paired(robot, camera, fit.offset_s)
    take = _spread(len(M), MAX_STREAM_SAMPLES)
    peer_take = _spread(len(peer_M), len(take))
    extra = {
        **speeds,
        "offset_error_ms": (fit.offset_s - offset_s) * 1e3,
        "offset_sigma_ms": fit.sigma_s * 1e3,
        "offset_z": (fit.offset_s - offset_s) / fit.sigma_s,
        "camera_poses_paired": float(len(M)),
        "solver_pairs": float(len(take)),
    }
    return Trial(M[take], B[take], X_TRUE, peer_M=peer_M[peer_take], peer_B=peer_B[peer_take], extra=extra)


def run_clock_offset(trials: int, seed: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    cases, targets = [], []
    for rate in CAMERA_HZ:
        for offset_ms in OFFSETS_MS:
            label = f"{rate:.0f} Hz, {offset_ms:.0f} ms"
            make = partial(clock_trial, seed, rate_hz=rate, offset_s=offset_ms / 1e3)
            tally = run_case(make, trials, VGR_OPTIONS)
            rec = case_record(label, {"camera_hz": rate, "offset_ms": offset_ms}, tally)
            z = np.asarray(tally.extra.get("offset_z", [np.nan]))
            rec["figures"]["offset_z_rms"] = float(np.sqrt(np.mean(z**2)))
            # coverage of the stated 1-sigma: 68.3 % / 95.4 % of the trials within 1 / 2 sigma when honest
            rec["figures"]["offset_within_1sd"] = float(np.mean(np.abs(z) <= 1.0))
            rec["figures"]["offset_within_2sd"] = float(np.mean(np.abs(z) <= 2.0))
            targets.append(beats_peers("clock_offset", rec))
            if rate == OFFSET_TARGET_HZ:
                worst = rec["figures"].get("offset_error_ms", {}).get("max_abs", float("nan"))
                ok = bool(worst <= OFFSET_TARGET_MS) and not tally.refusals
                targets.append(check("clock_offset", label, "worst |offset error| ms", worst, OFFSET_TARGET_MS, ok))
            cases.append(rec)
    return cases, targets


# --------------------------------------------------------------------------- 2. outliers


def perturb(T: F64, noise: PoseNoise, rng: np.random.Generator, tails: str) -> F64:
    """Measured poses: Gaussian decoupled noise (``simulate.perturb_poses``), or Student-t with 3
    dof scaled to the same sd (t3's variance is 3)."""
    if tails == "gaussian":
        return sim.perturb_poses(T, noise, rng)
    return retract(T, rng.standard_t(3.0, size=(len(T), 6)) / np.sqrt(3.0) * noise.sigmas6())


def view_tilt(B: F64) -> tuple[F64, F64]:
    """Per camera pose T_cam_target: the angle (rad) between the target's normal and its line of
    sight to the camera, and the unit axis perpendicular to both (camera frame)."""
    to_cam = -B[:, :3, 3] / np.linalg.norm(B[:, :3, 3], axis=1)[:, None]
    normal = B[:, :3, 2]
    axis = np.cross(normal, to_cam)
    s = np.linalg.norm(axis, axis=1)
    return np.arctan2(s, np.einsum("ij,ij->i", normal, to_cam)), axis / np.maximum(s, 1e-12)[:, None]


def _unit(rng: np.random.Generator, n: int) -> F64:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def corrupt(B: F64, k: int, kind: str, rng: np.random.Generator) -> tuple[F64, Mask, list[float]]:
    """*k* camera poses made outliers of *kind*: the poses, the outlier mask, and for flips the
    flip angles (deg)."""
    n = len(B)
    tilt, axis = view_tilt(B)
    if kind == "planar_flip":
        eligible = np.flatnonzero(tilt >= np.deg2rad(MIN_FLIP_TILT_DEG))
        idx = rng.choice(eligible, k, replace=False) if len(eligible) >= k else np.argsort(-tilt)[:k]
    else:
        idx = rng.choice(n, k, replace=False)
    out = B.copy()
    angles: list[float] = []
    if kind == "random_pose":
        out[idx, :3, :3] = Rotation.random(k, rng=rng).as_matrix()
        out[idx, :3, 3] += rng.normal(0.0, RANDOM_POSE_TRANS_SD_M, size=(k, 3))
    elif kind == "planar_flip":
        turn = axis[idx] * (2.0 * tilt[idx])[:, None]
        out[idx, :3, :3] = Rotation.from_rotvec(turn).as_matrix() @ B[idx, :3, :3]
        angles = np.rad2deg(2.0 * tilt[idx]).tolist()
    elif kind == "gross_error":
        dt = _unit(rng, k) * rng.uniform(*GROSS_MM, size=(k, 1)) * 1e-3
        dr = _unit(rng, k) * np.deg2rad(rng.uniform(*GROSS_DEG, size=(k, 1)))
        out[idx] = retract(B[idx], np.column_stack([dt, dr]))
    else:
        raise ValueError(f"unknown outlier kind {kind!r}")
    bad = np.zeros(n, bool)
    bad[idx] = True
    return out, bad, angles


def outlier_trial(seed: int, trial: int, kind: str, fraction: float, tails: str) -> Trial:
    """One trial; the scene and the noise are shared by every kind and fraction (paired cases)."""
    scene = sim.viewing_scene(_rng(seed, 2, trial), OUTLIER_POSES, SETUP)
    noise_rng = _rng(seed, 2, trial, 1 + TAILS.index(tails))
    M = perturb(scene.T_base_tcp, ROBOT_NOISE, noise_rng, tails)
    B = perturb(scene.T_cam_target, CAMERA_NOISE, noise_rng, tails)
    k = round(fraction * len(B))
    if k == 0:
        return Trial(M, B, scene.X, outliers=np.zeros(len(B), bool))
    rng = _rng(seed, 2, trial, 10 + OUTLIER_KINDS.index(kind), round(100 * fraction))
    B, bad, angles = corrupt(B, k, kind, rng)
    extra = {"flip_angle_deg": float(np.median(angles))} if angles else {}
    return Trial(M, B, scene.X, outliers=bad, extra=extra)


def run_outliers(trials: int, seed: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    cases, targets = [], []
    for tails in TAILS:
        plan = [("none", 0.0)] + [(kind, f) for kind in OUTLIER_KINDS for f in OUTLIER_FRACTIONS]
        for kind, fraction in plan:
            label = f"{tails} {kind} {fraction:.0%}"
            make = partial(outlier_trial, seed, kind=kind, fraction=fraction, tails=tails)
            tally = run_case(make, trials, VGR_OPTIONS)
            params = {"tails": tails, "kind": kind, "fraction": fraction, "poses": OUTLIER_POSES}
            rec = case_record(label, params, tally)
            targets.append(beats_peers("outliers", rec))
            if fraction == 0.0:
                rate = rec["vgr"].get("false_flag_rate", float("nan"))
                ok = bool(rate <= FALSE_FLAG_TARGET)
                targets.append(check("outliers", label, "vgr false-flag rate", rate, FALSE_FLAG_TARGET, ok))
            cases.append(rec)
    return cases, targets


# --------------------------------------------------------------------------- 3.-5. static samples


def static_trial(
    seed: int,
    condition: int,
    trial: int,
    n: int,
    camera: PoseNoise,
    *,
    scale: float = 1.0,
    limit_deg: float | None = None,
) -> Trial:
    """viewing_scene's poses with Gaussian noise (robot ROBOT_NOISE), the camera translations times
    *scale*, the view's tilt and roll limited to *limit_deg* when given."""
    rng = _rng(seed, condition, trial)
    if limit_deg is None:
        scene = sim.viewing_scene(rng, n, SETUP)
    else:
        scene = sim.viewing_scene(rng, n, SETUP, max_tilt_deg=limit_deg, max_roll_deg=limit_deg)
    noise_rng = _rng(seed, condition, trial, 1)
    M = sim.perturb_poses(scene.T_base_tcp, ROBOT_NOISE, noise_rng)
    B = sim.perturb_poses(scene.T_cam_target, camera, noise_rng)
    B[:, :3, 3] *= scale
    return Trial(M, B, scene.X)


def run_static(
    condition: str, cid: int, plan: list[tuple[str, dict[str, Any], dict[str, Any]]], trials: int, seed: int
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Cases of static_trial: (label, params for the record, static_trial's arguments)."""
    cases, targets = [], []
    for label, params, kw in plan:
        tally = run_case(partial(static_trial, seed, cid, **kw), trials, VGR_OPTIONS)
        rec = case_record(label, params, tally)
        targets.append(beats_peers(condition, rec))
        cases.append(rec)
    return cases, targets


def covariance_trial(seed: int, trial: int, n: int) -> Trial:
    """viewing_scene's poses, the robot with ROBOT_NOISE, each camera pose with its own covariance
    (``simulate.depth_covariances``), which the trial carries."""
    scene = sim.viewing_scene(_rng(seed, 3, trial, 7), n, SETUP)
    noise_rng = _rng(seed, 3, trial, 8)
    C = sim.depth_covariances(scene.T_cam_target, noise_rng)
    M = sim.perturb_poses(scene.T_base_tcp, ROBOT_NOISE, noise_rng)
    B = sim.perturb_poses_cov(scene.T_cam_target, C, noise_rng)
    return Trial(M, B, scene.X, camera_covariances=C)


def run_covariance_cases(trials: int, seed: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The anisotropic condition's per-sample covariance cases: vgr with the covariances against the
    peers, and vgr without them on the same trials."""
    cases, targets = [], []
    for n in ANISOTROPIC_POSES:
        make = partial(covariance_trial, seed, n=n)
        label = f"{COVARIANCE_CASE}, {n} poses"
        params = {"camera_noise": "simulate.depth_covariances (per view)", "poses": n, "vgr": "camera_covariances="}
        rec = case_record(label, params, run_case(make, trials, VGR_WITH_COVARIANCES))
        probe = case_record("probe", {}, run_case(make, trials, VGR_OPTIONS, peers=False))
        rec["vgr_without_covariances"] = {"errors": probe["methods"]["vgr"], **probe["vgr"]}
        targets.append(beats_peers("anisotropic", rec))
        with_cov = rec["methods"]["vgr"]["trans_median_mm"]
        without = probe["methods"]["vgr"]["trans_median_mm"]
        ok = bool(with_cov <= without)
        target = "vgr with covariances: median trans <= vgr without"
        targets.append(check("anisotropic", label, target, with_cov, without, ok))
        cases.append(rec)
    return cases, targets


def run_anisotropic(trials: int, seed: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    plan = []
    for name, noise in ANISOTROPIC.items():
        for n in ANISOTROPIC_POSES:
            params = {"camera_noise": noise.describe(), "poses": n}
            plan.append((f"{name}, {n} poses", params, {"n": n, "camera": noise}))
    cases, targets = run_static("anisotropic", 3, plan, trials, seed)
    more_cases, more_targets = run_covariance_cases(trials, seed)
    return cases + more_cases, targets + more_targets


def vgr_scale_options() -> tuple[Options | None, str]:
    """vgr's options for an unknown camera scale, or None and why not."""
    if "scale" in SolverOptions.__annotations__:
        return {**VGR_OPTIONS, "scale": "free"}, 'calibrate_hand_eye(..., scale="free")'
    return None, "not supported: SolverOptions (plugins/calibration/handeye/solver.py) has no 'scale' option"


def run_unknown_scale(trials: int, seed: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    options, note = vgr_scale_options()
    cases, targets = [], []
    for s in SCALES:
        make = partial(static_trial, seed, 4, n=SCALE_POSES, camera=CAMERA_NOISE, scale=s)
        tally = run_case(make, trials, options)
        rec = case_record(f"scale {s:g}", {"scale": s, "poses": SCALE_POSES}, tally)
        rec["vgr"]["note"] = note
        if "camera_scale" in tally.extra:  # metres per camera unit: the truth is 1 / s
            rel = np.abs(np.asarray(tally.extra["camera_scale"]) * s - 1.0)
            rec["figures"]["camera_scale_rel_error"] = {"median": float(np.median(rel)), "max_abs": float(rel.max())}
        # what vgr says about such data called without the option (not its result here)
        probe = case_record("probe", {}, run_case(make, trials, VGR_OPTIONS, peers=False))
        rec["vgr_without_scale_option"] = {"errors": probe["methods"]["vgr"], **probe["vgr"]}
        rec["vgr_without_scale_option"]["figures"] = probe.get("figures", {})
        targets.append(beats_peers("unknown_scale", rec))
        cases.append(rec)
    return cases, targets


def run_poses(trials: int, seed: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    plan: list[tuple[str, dict[str, Any], dict[str, Any]]]
    plan = [(f"{n} poses", {"poses": n}, {"n": n, "camera": CAMERA_NOISE}) for n in POSE_COUNTS]
    for n, lim in WEAK_MOTION:
        params = {"poses": n, "max_tilt_deg": lim, "max_roll_deg": lim}
        plan.append((f"weak {lim:g} deg, {n} poses", params, {"n": n, "camera": CAMERA_NOISE, "limit_deg": lim}))
    return run_static("poses", 5, plan, trials, seed)


CONDITIONS: dict[str, Callable[[int, int], tuple[list[dict[str, Any]], list[dict[str, Any]]]]] = {
    "clock_offset": run_clock_offset,
    "outliers": run_outliers,
    "anisotropic": run_anisotropic,
    "unknown_scale": run_unknown_scale,
    "poses": run_poses,
}


# --------------------------------------------------------------------------- output


VERDICT_SHORT = {"warning": "warn", "degenerate": "degen", "input_error": "input-err", "not_supported": "n/a"}


def _fmt(x: float | None, digits: int = 2) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def case_note(rec: dict[str, Any]) -> str:
    """The condition's own figures of a case, for the table."""
    fig, vgr = rec.get("figures", {}), rec["vgr"]
    parts = []
    if "offset_error_ms" in fig:
        e, s = fig["offset_error_ms"], fig["offset_sigma_ms"]
        parts.append(f"dt {_fmt(e['median'])} (max {_fmt(e['max_abs'])}) ms, sd {_fmt(s['median'])}")
        parts.append(f"z {_fmt(fig['offset_z_rms'], 1)}")
        if "offset_within_1sd" in fig:
            parts.append(f"in 1/2 sd {100 * fig['offset_within_1sd']:.0f}/{100 * fig['offset_within_2sd']:.0f}%")
    if "false_flag_rate" in vgr:
        parts.append(f"ff {100 * vgr['false_flag_rate']:.1f}%")
        if np.isfinite(vgr["missed_outlier_rate"]):
            parts.append(f"miss {100 * vgr['missed_outlier_rate']:.0f}%")
    if vgr["verdicts"].get("not_supported"):
        parts.append("vgr not supported")
    if "camera_scale_rel_error" in fig:
        parts.append(f"scale err {100 * fig['camera_scale_rel_error']['median']:.2f}%")
    probe = rec.get("vgr_without_scale_option")
    if probe:
        parts.append("unscaled call: " + " ".join(f"{k} {v}" for k, v in probe["verdicts"].items()))
    without = rec.get("vgr_without_covariances")
    if without:
        e = without["errors"]
        parts.append(f"vgr without cov {_fmt(e['trans_median_mm'])} / {_fmt(e['trans_p95_mm'])} mm")
        if "false_flag_rate" in vgr and "false_flag_rate" in without:
            parts.append(f"ff without {100 * without['false_flag_rate']:.1f}%")
    return ", ".join(p for p in parts if p)


def print_condition(
    console: Console, name: str, cases: list[dict[str, Any]], targets: list[dict[str, Any]], quick: bool
) -> None:
    title = f"{name}: T_tcp_cam translation error, median mm (vgr: median / p95, rot median deg)"
    table = Table(title=title + (" - QUICK, not results" if quick else ""))
    for col in ("case", "vgr mm", "vgr deg", "verdicts", *(SHORT[m] for m in PEERS), "figures", "vs peers"):
        table.add_column(col, justify="left" if col in ("case", "verdicts", "figures") else "right")
    vs_peers = ("vgr median", "vgr refused")  # (beats_peers' two forms)
    beat = {t["case"]: t["passed"] for t in targets if t["target"].startswith(vs_peers)}
    for rec in cases:
        m = rec["methods"]
        v = m["vgr"]
        verdicts = " ".join(f"{VERDICT_SHORT.get(k, k)} {n}" for k, n in sorted(rec["vgr"]["verdicts"].items()))
        row = [rec["case"], f"{_fmt(v['trans_median_mm'])} / {_fmt(v['trans_p95_mm'])}", _fmt(v["rot_median_deg"], 3)]
        row += [verdicts, *(_fmt(m[p]["trans_median_mm"]) for p in PEERS), case_note(rec)]
        row.append("[green]PASS[/]" if beat.get(rec["case"]) else "[red]FAIL[/]")
        table.add_row(*row)
    console.print(table)
    for t in targets:
        if not t["target"].startswith("vgr median"):  # (a refusal judged right is said here too)
            verdict = "[green]PASS[/]" if t["passed"] else "[red]FAIL[/]"
            console.print(f"  {verdict} {t['case']}: {t['target']} = {_fmt(t['value'], 3)} (limit {t['limit']:g})")
    n_pass = sum(t["passed"] for t in targets)
    console.print(f"  {name}: {n_pass} of {len(targets)} targets pass")


def merged(out: Path, part: dict[str, Any]) -> dict[str, Any]:
    """*part* (a run of some conditions) merged into the result file at *out*: its conditions and their
    targets replace those there, the rest is kept, and ``partial_runs`` records the run. *part* alone
    when there is no such file; an error when the file's seed, trials or quick mark differ."""
    if not out.exists():
        return part
    full = json.loads(out.read_text())
    for key in ("seed", "trials", "quick"):
        if full.get(key) != part[key]:
            raise SystemExit(f"{out}: {key} {full.get(key)!r} there, {part[key]!r} here; use --out for another file")
    names = set(part["conditions"])
    for name, cond in part["conditions"].items():
        full["conditions"][name] = cond
    full["targets"] = [t for t in full["targets"] if t["condition"] not in names] + part["targets"]
    run = {k: part[k] for k in ("command", "machine", "wall_time_s")}
    full.setdefault("partial_runs", []).append({"conditions": sorted(names), **run})
    return full


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--trials", type=int, default=None, help="trials per case (default 30, --quick 3)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--quick", action="store_true", help="3 trials per case; a smoke test, not results")
    ap.add_argument("--out", type=Path, default=None, help="result file (default benchmarks/results/...)")
    ap.add_argument(
        "--condition",
        action="append",
        choices=list(CONDITIONS),
        help="run only this condition (repeatable); its entries replace those in the result file",
    )
    args = ap.parse_args(argv)
    chosen = {name: CONDITIONS[name] for name in (args.condition or CONDITIONS)}
    trials = args.trials or (3 if args.quick else 30)
    out = args.out or ROOT / "benchmarks" / "results" / f"handeye_streams{'_quick' if args.quick else ''}.json"
    console = Console(width=200)
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # its failures are counted instead
    if args.quick:
        console.print("[yellow]--quick: a smoke test of the script; its figures are not results[/]")
    t0 = time.time()
    result: dict[str, Any] = {
        "benchmark": "handeye_streams",
        "quick": bool(args.quick),
        "command": shlex.join(["python", *(sys.argv if argv is None else ["benchmarks/handeye_streams.py", *argv])]),
        "seed": args.seed,
        "trials": trials,
        "parameters": {
            "setup": SETUP,
            "vgr_options": "setup given, noise estimated",
        },
        "machine": {**machine(), "opencv": cv2.__version__},
        "conditions": {},
        "targets": [],
    }
    if args.quick:
        result["note"] = f"quick run ({trials} trials per case): a smoke test of the script, not a measurement"
    for name, run in chosen.items():
        c0 = time.time()
        cases, targets = run(trials, args.seed)
        result["conditions"][name] = {"cases": cases, "wall_time_s": time.time() - c0}
        result["targets"] += targets
        print_condition(console, name, cases, targets, args.quick)
    result["wall_time_s"] = time.time() - t0
    if args.condition:
        result = merged(out, result)
    result["targets_summary"] = {
        name: {"passed": sum(t["passed"] for t in ts), "of": len(ts)}
        for name in result["conditions"]
        for ts in [[t for t in result["targets"] if t["condition"] == name]]
    }
    write_result(out, _plain(result))
    console.print(f"wrote {out} ({time.time() - t0:.0f} s)")
    return result


if __name__ == "__main__":
    main()
