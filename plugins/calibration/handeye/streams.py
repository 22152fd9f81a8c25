"""Hand-eye samples from two pose streams with their own clocks: robot poses at the controller's rate,
camera poses at the camera's, stamped by clocks that may be apart by a constant offset.

Pairing by nearest stamp turns a clock offset into a pose error of (offset x speed): 20 ms at
0.5 rad/s is 10 mrad. So the camera stream is paired with the robot stream *interpolated* at the
camera stamps (:func:`interpolate`: rotation by spherical linear interpolation, translation
linearly, never across a gap of more than ``MAX_GAP_FACTOR`` robot periods), and the offset is
estimated:

1. **coarse** (:func:`coarse_offset`): the angular speed of the flange and of the camera's view of
   the target are the same signal (a rigid transform on either side does not change how fast a
   frame turns), so the lag that maximises their normalised cross-correlation, on a common grid,
   is the offset to within the grid step;
2. **fine** (:func:`fit_offset`): the offset as a parameter of the hand-eye problem, profiled: for
   each trial offset the camera samples are paired with the robot interpolated there, the
   closed-form hand-eye transform (Park & Martin 1994, ``closed_form.park_martin``) is fitted and
   the pose chains' disagreement (``chain_poses``, each sample's own view of the other unknown,
   rotation and translation each in units of its own spread at the coarse offset) is the cost; a
   bounded scalar search (Brent) finds the minimum. Its 1-sigma is the sandwich (Huber 1967;
   White 1982, *Maximum likelihood estimation of misspecified models*) of this M-estimate: the
   spread of the per-sample scores (each sample's cost derivative at the minimum, the closed form
   held) over the squared curvature of the profile cost, ``sum g_i^2 / C''^2``. It needs no
   model of the residuals' sizes: stamp jitter makes a sample's pose error grow with the speed of
   the motion, i.e. largest where the offset's information is, and the profile likelihood's
   Fisher information (the curvature alone, as if every sample were equally noisy) stated a 1-sigma
   about 1.4x too small (``benchmarks/handeye_streams.py``, 1 ms jitter).

Convention: ``robot_time = camera_time + offset_s``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from plugins.calibration.handeye.closed_form import park_martin
from plugins.calibration.handeye.problem import Setup, chain_poses, relative_motions

F64 = NDArray[np.float64]

MAX_GAP_FACTOR = 3.0  # no interpolation across a gap longer than this many median robot periods


@dataclass(frozen=True)
class PoseStream:
    """Poses ``T`` (n, 4, 4) at strictly increasing ``stamps_s`` (n,), seconds of one clock."""

    stamps_s: F64
    T: F64

    def __post_init__(self) -> None:
        s, T = np.asarray(self.stamps_s, float), np.asarray(self.T, float)
        if s.ndim != 1 or T.shape != (len(s), 4, 4):
            raise ValueError(f"a pose stream needs n stamps and n 4x4 poses, got {s.shape} and {T.shape}")
        if len(s) < 2 or not np.all(np.diff(s) > 0):
            raise ValueError("a pose stream needs at least 2 poses at strictly increasing stamps")
        object.__setattr__(self, "stamps_s", s)
        object.__setattr__(self, "T", T)

    @property
    def period_s(self) -> float:
        return float(np.median(np.diff(self.stamps_s)))


def interpolate(stream: PoseStream, t_s: F64) -> tuple[F64, NDArray[np.bool_]]:
    """The stream's poses at times *t_s* (its clock), and which of them could be had: inside the
    stream, and not across a gap of more than MAX_GAP_FACTOR periods (the others are NaN)."""
    s, T = stream.stamps_s, stream.T
    t = np.asarray(t_s, float)
    k = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(s) - 2)
    span = s[k + 1] - s[k]
    ok = (t >= s[0]) & (t <= s[-1]) & (span <= MAX_GAP_FACTOR * stream.period_s)
    u = np.clip((t - s[k]) / span, 0.0, 1.0)
    R0 = Rotation.from_matrix(T[k, :3, :3])
    step = (R0.inv() * Rotation.from_matrix(T[k + 1, :3, :3])).as_rotvec()
    out = np.full((len(t), 4, 4), np.nan)
    out[:, :3, :3] = (R0 * Rotation.from_rotvec(step * u[:, None])).as_matrix()
    out[:, :3, 3] = (1.0 - u)[:, None] * T[k, :3, 3] + u[:, None] * T[k + 1, :3, 3]
    out[:, 3] = [0.0, 0.0, 0.0, 1.0]
    out[~ok] = np.nan
    return out, ok


def angular_speed(stream: PoseStream) -> tuple[F64, F64]:
    """How fast the stream's frame turns (rad/s), at the midpoints of its samples."""
    R = Rotation.from_matrix(stream.T[:, :3, :3])
    turn = (R[:-1].inv() * R[1:]).magnitude()
    s = stream.stamps_s
    return 0.5 * (s[:-1] + s[1:]), turn / np.diff(s)


def coarse_offset(robot: PoseStream, camera: PoseStream, max_offset_s: float, step_s: float | None = None) -> float:
    """The offset (robot time - camera time) within +-*max_offset_s* that best lines up the two
    streams' angular speeds (normalised cross-correlation on a grid of *step_s*, default a quarter
    of the camera's period)."""
    step = step_s or camera.period_s / 4.0
    tr, wr = angular_speed(robot)
    tc, wc = angular_speed(camera)
    lags = np.arange(-max_offset_s, max_offset_s + 0.5 * step, step)
    grid = np.arange(tc[0], tc[-1], step)
    cam = np.interp(grid, tc, wc)
    best, best_score = 0.0, -np.inf
    for lag in lags:
        t = grid + lag
        inside = (t >= tr[0]) & (t <= tr[-1])
        if inside.sum() < 8:
            continue
        a, b = cam[inside], np.interp(t[inside], tr, wr)
        a, b = a - a.mean(), b - b.mean()
        denom = float(np.linalg.norm(a) * np.linalg.norm(b))
        score = float(a @ b) / denom if denom > 0 else -np.inf
        if score > best_score:
            best, best_score = float(lag), score
    return best


def paired(robot: PoseStream, camera: PoseStream, offset_s: float) -> tuple[F64, F64, NDArray[np.bool_]]:
    """Robot poses interpolated at the camera stamps + *offset_s*, the camera poses, and which
    camera samples could be paired (the robot stream covers them)."""
    M, ok = interpolate(robot, camera.stamps_s + offset_s)
    return M[ok], camera.T[ok], ok


def _chain_residuals(setup: Setup, M: F64, B: F64, held: tuple[F64, F64] | None = None) -> tuple[F64, F64]:
    """Each sample's disagreement with the others on the second unknown: rotation (rad) and
    translation (m) of ``Y_i`` from their mean, after the closed-form X of these pairs; with
    *held* ``(X, Y_mean)`` from elsewhere instead (a sample's score at fixed X and Y)."""
    X = park_martin(relative_motions(setup, M, B)) if held is None else held[0]
    Y = chain_poses(setup, M, X, B)
    if held is None:
        R_mean, t_mean = Rotation.from_matrix(Y[:, :3, :3]).mean(), Y[:, :3, 3].mean(axis=0)
    else:
        R_mean, t_mean = Rotation.from_matrix(held[1][:3, :3]), held[1][:3, 3]
    rot = (R_mean.inv() * Rotation.from_matrix(Y[:, :3, :3])).as_rotvec()
    return rot, Y[:, :3, 3] - t_mean


def _held(setup: Setup, M: F64, B: F64) -> tuple[F64, F64]:
    """The closed-form X of these pairs and the mean of the samples' Y (rotation mean, translation
    mean) as one pose."""
    X = park_martin(relative_motions(setup, M, B))
    Y = chain_poses(setup, M, X, B)
    Y_mean = np.eye(4)
    Y_mean[:3, :3] = Rotation.from_matrix(Y[:, :3, :3]).mean().as_matrix()
    Y_mean[:3, 3] = Y[:, :3, 3].mean(axis=0)
    return X, Y_mean


@dataclass(frozen=True)
class OffsetFit:
    """The clock offset (robot time - camera time) and its 1-sigma, s; the coarse start; how many
    camera samples were paired at the offset; the pose chains' translation spread there (m RMS,
    what tells a wrong set-up: its chains do not agree at any offset)."""

    offset_s: float
    sigma_s: float
    coarse_s: float
    n_paired: int
    chain_rms_m: float


MAX_PROFILE_SAMPLES = 80  # camera samples the profile cost uses (evenly spread): 3160 relative motions


def fit_offset(setup: Setup, robot: PoseStream, camera: PoseStream, *, max_offset_s: float = 0.5) -> OffsetFit:
    """The clock offset by the two steps of the module docstring. The profile cost uses the same
    camera samples at every trial offset (up to MAX_PROFILE_SAMPLES, evenly spread over those the
    robot stream covers at every offset tried), so its values compare."""
    coarse = coarse_offset(robot, camera, max_offset_s)
    half = max(2.0 * camera.period_s, 2.0 * robot.period_s)
    lo, hi = robot.stamps_s[0] - (coarse - half), robot.stamps_s[-1] - (coarse + half)
    inside = np.flatnonzero((camera.stamps_s >= lo) & (camera.stamps_s <= hi))
    if len(inside) < 3:
        raise ValueError(f"only {len(inside)} camera pose(s) fall inside the robot stream: the streams do not overlap")
    take = inside[np.unique(np.linspace(0, len(inside) - 1, min(MAX_PROFILE_SAMPLES, len(inside))).round().astype(int))]
    cams = PoseStream(camera.stamps_s[take], camera.T[take])
    M, B, _ = paired(robot, cams, coarse)
    rot, trans = _chain_residuals(setup, M, B)
    s_rot = max(float(np.sqrt(np.mean(rot**2))), 1e-9)
    s_trans = max(float(np.sqrt(np.mean(trans**2))), 1e-12)

    def per_sample(offset: float, held: tuple[F64, F64] | None = None) -> F64:
        Mo, Bo, ok = paired(robot, cams, offset)
        if not ok.all():  # (cannot happen inside the bracket; outside it the cost is not defined)
            return np.full(len(cams.stamps_s), np.inf)
        r, t = _chain_residuals(setup, Mo, Bo, held)
        return np.sum(r**2, axis=1) / s_rot**2 + np.sum(t**2, axis=1) / s_trans**2

    def cost(offset: float) -> float:
        return float(np.sum(per_sample(offset)))

    res = minimize_scalar(cost, bounds=(coarse - half, coarse + half), method="bounded", options={"xatol": 1e-6})
    best = float(res.x)
    n_paired = int(paired(robot, camera, best)[2].sum())
    spread = float(np.sqrt(np.mean(_chain_residuals(setup, *paired(robot, cams, best)[:2])[1] ** 2)))
    held = _held(setup, *paired(robot, cams, best)[:2])
    return OffsetFit(best, _sandwich_sigma(cost, partial(per_sample, held=held), best), coarse, n_paired, spread)


def _sandwich_sigma(cost: Callable[[float], float], per_sample: Callable[[float], F64], best: float) -> float:
    """1-sigma of the offset (module docstring): ``sqrt(sum g_i^2) / C''`` with ``g_i`` the samples'
    cost derivatives at *best* (X and Y held) and ``C''`` the profile cost's curvature there."""
    h = 1e-4
    curv = (cost(best + h) - 2.0 * cost(best) + cost(best - h)) / h**2
    g = (per_sample(best + h) - per_sample(best - h)) / (2.0 * h)
    if not np.isfinite(curv) or curv <= 0 or not np.all(np.isfinite(g)):
        return float("nan")
    return float(np.sqrt(np.sum(g**2)) / curv)
