"""Simulated robot controller (library part; the zenoh service stage wraps it later).

Behaves like a vendor controller in simulated time:

* ``move_j`` (joint-space, synchronised axes) and ``move_l`` (TCP moves on a straight line with
  slerped orientation) with speed and acceleration, trapezoidal time law; ``move_j_pose`` is a
  joint move to a Cartesian target (IK first). Default speeds/accelerations are URScript's.
* Time is whatever the injected ``clock`` (a callable returning seconds, e.g. ``SimClock``) says;
  the controller never sleeps. A move starts at the clock's time when it is commanded and the
  state at any time ``t`` (past or future of the plan) is computed on demand.
* Targets out of the joint limits, unreachable, with NaN, or a linear path through a singularity are
  refused with a reason and no motion; so is a move commanded while another is running ("busy").
* Command ids are idempotent: a second command with an id already seen is not executed; the first
  result is returned again with ``duplicate=True``.
* ``halt()`` stops the move in progress on its path, decelerating at the move's own acceleration
  (a controller's stop, URScript ``stopj``/``stopl``); its result then says ``halted`` and ends where
  the robot came to rest. It may be called from another thread than the one commanding the moves
  (the run's stop): the controller's state is guarded by a lock.
* Reported joint angles and ``T_base_tcp`` are the nominal model's (what the real controller would
  report from its encoders and its model). The truth (``q_actual``, ``T_world_tcp_actual``) comes
  from the :class:`RobotWithEffects`, evaluated with the per-joint approach directions the
  controller records (for backlash), the time since warm-up start (thermal drift) and the payload.
"""

from __future__ import annotations

import bisect
import functools
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Concatenate, Literal, ParamSpec, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import as_transform, exp_so3, log_so3
from plugins.robot.effects.base import SampleContext
from plugins.robot.ik import solve_ik
from plugins.robot.kinematics import RobotModel
from plugins.robot.with_effects import RobotWithEffects
from plugins.sim.motion_profile import Profile, trapezoid

F64 = NDArray[np.float64]
MoveKind = Literal["movej", "movel"]
_P = ParamSpec("_P")
_R = TypeVar("_R")

# URScript defaults
MOVEJ_SPEED = 1.05  # rad/s
MOVEJ_ACCEL = 1.4  # rad/s^2
MOVEL_SPEED = 0.25  # m/s
MOVEL_ACCEL = 1.2  # m/s^2
MOVEL_ANGULAR_SPEED = 1.05  # rad/s of the tool orientation
MOVEL_ANGULAR_ACCEL = 1.4  # rad/s^2

TIME_EPS_S = 1e-9  # clocks count integer nanoseconds: a move has arrived within 1 ns of its end
MOVEL_STEP_M = 0.005  # waypoint spacing used to validate a linear path
MOVEL_STEP_RAD = 0.02
MOVEL_MAX_JOINT_STEP_RAD = 0.25  # a larger jump between waypoints means a singularity/branch flip


@dataclass(frozen=True)
class MoveResult:
    """Answer to a move command. ``end_s`` is the sim time the robot arrives (== start if refused)."""

    command_id: str
    kind: MoveKind
    accepted: bool
    reason: str
    start_s: float
    end_s: float
    q_target: F64 | None = None
    duplicate: bool = False
    halted: bool = False  # stopped by halt() before its target (end_s: when it came to rest)

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True)
class RobotState:
    """Controller state at ``t_s``. ``q``/``T_base_tcp`` are reported; ``*_actual`` are the truth."""

    t_s: float
    q: F64
    qd: F64
    moving: bool
    command_id: str | None
    approach_direction: F64
    T_base_tcp: F64
    q_actual: F64
    T_world_tcp_actual: F64


@dataclass
class _Segment:
    command_id: str
    kind: MoveKind
    t0: float
    q0: F64
    q1: F64
    profile: Profile  # over the path parameter s in [0, 1] (halted: to rest at profile.distance)
    direction_after: F64
    # move_l only
    path_s: F64 | None = None
    path_q: F64 | None = None
    pose0: tuple[F64, F64] | None = None  # (p0, R0)
    pose_delta: tuple[F64, F64] | None = None  # (p1 - p0, log(R0^T R1))
    cache: dict = field(default_factory=dict)
    q_rest: F64 | None = None  # where a halted move came to rest (else it rests at q1)

    @property
    def t1(self) -> float:
        return self.t0 + self.profile.duration


def _locked(
    method: Callable[Concatenate[SimRobotController, _P], _R],
) -> Callable[Concatenate[SimRobotController, _P], _R]:
    """A command of the controller: run under its lock (a halt may come from another thread)."""

    @functools.wraps(method)
    def locked(self: SimRobotController, *args: _P.args, **kwargs: _P.kwargs) -> _R:
        with self._lock:
            return method(self, *args, **kwargs)

    return locked


class SimRobotController:
    """Simulated controller of one robot (see module docstring)."""

    def __init__(
        self,
        nominal: RobotModel,
        clock: Callable[[], float],
        *,
        true_robot: RobotWithEffects | None = None,
        q_initial: ArrayLike | None = None,
        payload_kg: float = 0.0,
        warmup_start_s: float | None = None,
        initial_direction: ArrayLike | float = 1.0,
        keep_moves: int = 200,
    ) -> None:
        self.nominal = nominal
        self.true_robot = true_robot if true_robot is not None else RobotWithEffects(nominal)
        if self.true_robot.nominal is not nominal and self.true_robot.nominal.dof != nominal.dof:
            raise ValueError("true robot and nominal model have different numbers of joints")
        self.clock = clock
        q0 = nominal.home if q_initial is None else nominal.check_joints(q_initial, name="q_initial")[0][0]
        if not nominal.within_limits(q0):
            raise ValueError("initial joints out of limits: " + "; ".join(nominal.limit_violations(q0)))
        self._q_initial = q0.copy()
        d = np.broadcast_to(np.asarray(initial_direction, dtype=float), (nominal.dof,)).copy()
        if not np.all(np.isin(d, (-1.0, 1.0))):
            raise ValueError("initial_direction must be +1 or -1 per joint")
        self._dir_initial = d
        self.payload_kg = float(payload_kg)
        self.warmup_start_s = float(clock()) if warmup_start_s is None else float(warmup_start_s)
        if int(keep_moves) < 2:
            raise ValueError(f"keep_moves must be at least 2, got {keep_moves}")
        self.keep_moves = int(keep_moves)
        self._segments: list[_Segment] = []  # the kept moves, in time order
        self._dir_before_kept = self._dir_initial  # approach direction before the oldest kept move
        self._forgot_moves = False
        self._results: OrderedDict[str, MoveResult] = OrderedDict()
        self._lock = threading.RLock()  # halt() comes from another thread than the moves

    # ----------------------------------------------------------------------------- state

    def _now(self) -> float:
        t = float(self.clock())
        if not np.isfinite(t):
            raise ValueError(f"clock returned {t}")
        return t

    def _segment_at(self, t: float) -> tuple[_Segment | None, bool]:
        """(segment in effect at t, whether it is still moving); None before the first move."""
        i = bisect.bisect_right(self._segments, t, key=lambda s: s.t0)
        if i == 0 and self._forgot_moves:
            raise ValueError(f"t = {t:.3f} s is before the {self.keep_moves} moves this controller keeps")
        seg = self._segments[i - 1] if i > 0 else None
        return seg, seg is not None and t < seg.t1 - TIME_EPS_S

    def _joints_at(self, seg: _Segment | None, t: float) -> tuple[F64, F64, F64]:
        """(q, qd, approach direction) at time t."""
        if seg is None:
            return self._q_initial.copy(), np.zeros(self.nominal.dof), self._dir_initial.copy()
        prev_dir = self._direction_before(seg)
        if t >= seg.t1 - TIME_EPS_S:
            q_end = seg.q1 if seg.q_rest is None else seg.q_rest
            return q_end.copy(), np.zeros(self.nominal.dof), seg.direction_after.copy()
        tau = t - seg.t0
        s = float(seg.profile.position(tau))
        sd = float(seg.profile.velocity(tau))
        if seg.kind == "movej":
            q = seg.q0 + s * (seg.q1 - seg.q0)
            qd = sd * (seg.q1 - seg.q0)
        else:
            q, dq_ds = self._movel_joints(seg, s)
            qd = sd * dq_ds
        moving = np.abs(qd) > 1e-12
        direction = np.where(moving, np.sign(qd), prev_dir)
        return q, qd, direction

    def _direction_before(self, seg: _Segment) -> F64:
        i = self._segments.index(seg)
        return self._segments[i - 1].direction_after if i > 0 else self._dir_before_kept

    def state(self, t_s: float | None = None) -> RobotState:
        """Reported and true state at ``t_s`` (default: the clock's now)."""
        with self._lock:
            return self._state(t_s)

    def _state(self, t_s: float | None = None) -> RobotState:
        t = self._now() if t_s is None else float(t_s)
        seg, moving = self._segment_at(t)
        q, qd, direction = self._joints_at(seg, t)
        ctx = SampleContext(
            t_s=np.array([t - self.warmup_start_s]),
            direction=direction[None, :],
            payload_kg=np.array([self.payload_kg]),
        )
        q_act = self.true_robot.actual_joints(q[None, :], ctx)[0]
        T_act = self.true_robot.fk(q[None, :], ctx)[0]
        return RobotState(
            t_s=t,
            q=q,
            qd=qd,
            moving=moving,
            command_id=None if seg is None else seg.command_id,
            approach_direction=direction,
            T_base_tcp=self.nominal.fk(q, frame="base"),
            q_actual=q_act,
            T_world_tcp_actual=T_act,
        )

    def is_moving(self, t_s: float | None = None) -> bool:
        with self._lock:
            t = self._now() if t_s is None else float(t_s)
            return self._segment_at(t)[1]

    def halt(self) -> MoveResult | None:
        """Stop the move in progress now, on its path, at its own deceleration; its result (also
        :meth:`result`) says ``halted`` and ends when the robot is at rest. None when at rest."""
        with self._lock:
            now = self._now()
            seg, moving = self._segment_at(now)
            if seg is None or not moving:
                return None
            profile = seg.profile.halted(now - seg.t0)
            s_rest = profile.distance
            if seg.kind == "movej":
                q_rest = seg.q0 + s_rest * (seg.q1 - seg.q0)
            else:
                q_rest = self._movel_joints(seg, s_rest)[0]
            seg.profile, seg.q_rest = profile, np.asarray(q_rest, dtype=float).copy()  # (under the lock)
            res = replace(self._results[seg.command_id], end_s=seg.t1, halted=True, reason="halted")
            self._results[seg.command_id] = res
            return res

    def result(self, command_id: str) -> MoveResult | None:
        return self._results.get(command_id)

    def set_payload(self, payload_kg: float) -> None:
        if not (np.isfinite(payload_kg) and payload_kg >= 0):
            raise ValueError(f"payload must be finite and >= 0 kg, got {payload_kg}")
        self.payload_kg = float(payload_kg)

    # ----------------------------------------------------------------------------- commands

    def _command(self, command_id: str, kind: MoveKind, plan: Callable[[float], _Segment]) -> MoveResult:
        """Run one move command: a repeated id returns its first result (``duplicate``), a command
        while a move runs is refused as busy; else *plan* (given the time now) makes the move's
        segment, which is accepted, or raises :class:`_RefusedError`, which refuses the command with
        its reason and moves nothing. Either result is kept under the id."""
        if not isinstance(command_id, str) or not command_id:
            raise ValueError("command_id must be a non-empty string")
        if command_id in self._results:
            return replace(self._results[command_id], duplicate=True)
        now = self._now()
        try:
            running, moving = self._segment_at(now)
            if moving:
                raise _RefusedError(f"busy: command {running.command_id!r} is moving until t = {running.t1:.3f} s")
            seg = plan(now)
        except _RefusedError as refusal:
            res = MoveResult(command_id, kind, False, str(refusal), now, now)
        else:
            self._keep(seg)
            res = MoveResult(seg.command_id, seg.kind, True, "ok", seg.t0, seg.t1, seg.q1.copy())
        self._results[command_id] = res
        while len(self._results) > 4 * self.keep_moves:
            self._results.popitem(last=False)
        return res

    def _keep(self, seg: _Segment) -> None:
        """Append an accepted move; forget the oldest beyond ``keep_moves``."""
        self._segments.append(seg)
        if len(self._segments) > self.keep_moves:
            self._dir_before_kept = self._segments[0].direction_after
            del self._segments[0]
            self._forgot_moves = True

    @_locked
    def move_j(
        self, command_id: str, q_target: ArrayLike, speed: float = MOVEJ_SPEED, accel: float = MOVEJ_ACCEL
    ) -> MoveResult:
        """Joint move to ``q_target`` (rad); ``speed``/``accel`` of the leading axis (rad/s, rad/s^2)."""
        return self._command(command_id, "movej", lambda now: self._plan_j(command_id, now, q_target, speed, accel))

    def _plan_j(self, cid: str, now: float, q_target: ArrayLike, speed: float, accel: float) -> _Segment:
        _check_limits(speed=speed, accel=accel)
        try:
            q1 = self.nominal.check_joints(q_target, name="q_target")[0][0]
        except ValueError as e:
            raise _RefusedError(str(e)) from None
        if not self.nominal.within_limits(q1):
            raise _RefusedError("target out of joint limits: " + "; ".join(self.nominal.limit_violations(q1)))
        return self._joint_segment(cid, now, self.state(now).q, q1, speed, accel)

    def _joint_segment(self, cid: str, now: float, q0: F64, q1: F64, speed: float, accel: float) -> _Segment:
        dq = q1 - q0
        adq = np.abs(dq)
        moving = adq > 1e-12
        prev = self.state(now).approach_direction
        direction = np.where(moving, np.sign(dq), prev)
        if not np.any(moving):
            return _Segment(cid, "movej", now, q0, q1, trapezoid(0.0, 1.0, 1.0), direction)
        v_lim = np.minimum(speed, self.nominal.max_speed)[moving] / adq[moving]
        a_lim = np.minimum(accel, self.nominal.max_accel)[moving] / adq[moving]
        profile = trapezoid(1.0, float(v_lim.min()), float(a_lim.min()))
        return _Segment(cid, "movej", now, q0, q1, profile, direction)

    @_locked
    def move_j_pose(
        self, command_id: str, T_base_tcp: ArrayLike, speed: float = MOVEJ_SPEED, accel: float = MOVEJ_ACCEL
    ) -> MoveResult:
        """Joint move to a Cartesian target (IK from the current joints, nearest branch first)."""

        def plan(now: float) -> _Segment:
            ik = solve_ik(self.nominal, self.nominal.T_world_base @ _target(T_base_tcp), self.state(now).q)
            if not ik.success:
                raise _RefusedError(f"{ik.status}: {ik.reason}")
            return self._plan_j(command_id, now, ik.q, speed, accel)

        return self._command(command_id, "movej", plan)

    @_locked
    def move_l(
        self,
        command_id: str,
        T_base_tcp: ArrayLike,
        speed: float = MOVEL_SPEED,
        accel: float = MOVEL_ACCEL,
        angular_speed: float = MOVEL_ANGULAR_SPEED,
        angular_accel: float = MOVEL_ANGULAR_ACCEL,
    ) -> MoveResult:
        """Linear TCP move to ``T_base_tcp`` (m/s, m/s^2 along the path; rad/s for the orientation).

        The whole path is checked before moving (IK at waypoints every 5 mm / 1.1 deg): unreachable
        points, joint limits and branch flips near singularities are refused. The time law is slowed
        down where needed so that no joint exceeds its speed or acceleration limit.
        """
        return self._command(
            command_id,
            "movel",
            lambda now: self._plan_l(command_id, now, T_base_tcp, speed, accel, angular_speed, angular_accel),
        )

    def _plan_l(
        self,
        cid: str,
        now: float,
        T_base_tcp: ArrayLike,
        speed: float,
        accel: float,
        angular_speed: float,
        angular_accel: float,
    ) -> _Segment:
        _check_limits(speed=speed, accel=accel, angular_speed=angular_speed, angular_accel=angular_accel)
        T1 = _target(T_base_tcp)
        st = self.state(now)
        T0 = st.T_base_tcp
        dp = T1[:3, 3] - T0[:3, 3]
        phi = log_so3(T0[:3, :3].T @ T1[:3, :3])
        L, th = float(np.linalg.norm(dp)), float(np.linalg.norm(phi))
        k = int(np.clip(np.ceil(max(L / MOVEL_STEP_M, th / MOVEL_STEP_RAD)), 2, 4000))
        s_grid = np.linspace(0.0, 1.0, k + 1)
        T_wb = self.nominal.T_world_base
        end = solve_ik(self.nominal, T_wb @ T1, st.q)
        if not end.success:
            raise _RefusedError(f"target {end.status}: {end.reason}")
        qs = [st.q]
        for s in s_grid[1:]:
            T_s = T_wb @ _interp_pose(T0[:3, 3], T0[:3, :3], dp, phi, s)
            ik = solve_ik(self.nominal, T_s, qs[-1], n_random_seeds=0, classify_failures=False)
            if not ik.success:
                where = f"{s * L * 1e3:.1f} mm along the path" if L > 0 else f"{s * 100:.0f} % of the rotation"
                raise _RefusedError(
                    f"the straight path cannot be followed within the joint limits at {where} "
                    f"(leaves the workspace or the limits); use move_j or add a via point"
                )
            if np.max(np.abs(ik.q - qs[-1])) > MOVEL_MAX_JOINT_STEP_RAD:
                raise _RefusedError(
                    f"path passes through or near a singularity at {s * L * 1e3:.1f} mm along the path "
                    "(joint solution jumps); use move_j or add a via point"
                )
            qs.append(ik.q)
        path_q = np.array(qs)
        dq_ds = np.diff(path_q, axis=0) / np.diff(s_grid)[:, None]
        peak = np.max(np.abs(dq_ds), axis=0)
        v_caps = [speed / L if L > 0 else np.inf, angular_speed / th if th > 0 else np.inf]
        a_caps = [accel / L if L > 0 else np.inf, angular_accel / th if th > 0 else np.inf]
        nz = peak > 1e-12
        v_caps += list(self.nominal.max_speed[nz] / peak[nz])
        a_caps += list(self.nominal.max_accel[nz] / peak[nz])
        direction = _last_motion_direction(np.diff(path_q, axis=0), st.approach_direction)
        if L == 0 and th == 0:
            profile = trapezoid(0.0, 1.0, 1.0)
        else:
            profile = trapezoid(1.0, float(min(v_caps)), float(min(a_caps)))
        return _Segment(
            cid,
            "movel",
            now,
            st.q,
            path_q[-1],
            profile,
            direction,
            path_s=s_grid,
            path_q=path_q,
            pose0=(T0[:3, 3].copy(), T0[:3, :3].copy()),
            pose_delta=(dp, phi),
        )

    def _movel_joints(self, seg: _Segment, s: float) -> tuple[F64, F64]:
        """Joints on the straight-line path at parameter s (IK seeded by the waypoint table)."""
        assert seg.path_s is not None and seg.path_q is not None and seg.pose0 and seg.pose_delta
        i = int(np.clip(np.searchsorted(seg.path_s, s) - 1, 0, len(seg.path_s) - 2))
        w = (s - seg.path_s[i]) / (seg.path_s[i + 1] - seg.path_s[i])
        q_lin = (1 - w) * seg.path_q[i] + w * seg.path_q[i + 1]
        dq_ds = (seg.path_q[i + 1] - seg.path_q[i]) / (seg.path_s[i + 1] - seg.path_s[i])
        if s in seg.cache:
            return seg.cache[s], dq_ds
        T_s = self.nominal.T_world_base @ _interp_pose(*seg.pose0, *seg.pose_delta, s)
        ik = solve_ik(self.nominal, T_s, q_lin, n_random_seeds=0, classify_failures=False)
        q = ik.q if ik.success else q_lin
        if len(seg.cache) > 256:
            seg.cache.clear()
        seg.cache[s] = q
        return q, dq_ds


class _RefusedError(Exception):
    """A move command the controller refuses before anything moves; the message says why."""


def _check_limits(**limits: float) -> None:
    """Refuse the first speed or acceleration (by keyword name) that is not a finite positive number."""
    for name, value in limits.items():
        if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
            raise _RefusedError(f"{name} must be a finite positive number, got {value!r}")


def _target(T_base_tcp: ArrayLike) -> F64:
    """The Cartesian target as a rigid 4x4, or refused with the reason it is not one."""
    try:
        return as_transform(T_base_tcp, name="target T_base_tcp")
    except ValueError as e:
        raise _RefusedError(str(e)) from None


def _last_motion_direction(steps: F64, previous: F64) -> F64:
    """Per joint: sign of the last non-zero step, or the previous direction if it never moved."""
    out = previous.copy()
    for j in range(steps.shape[1]):
        nz = np.flatnonzero(np.abs(steps[:, j]) > 1e-12)
        if nz.size:
            out[j] = np.sign(steps[nz[-1], j])
    return out


def _interp_pose(p0: F64, R0: F64, dp: F64, phi: F64, s: float) -> F64:
    T = np.eye(4)
    T[:3, :3] = R0 @ exp_so3(s * phi)
    T[:3, 3] = p0 + s * dp
    return T
