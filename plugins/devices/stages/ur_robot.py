"""``ur_robot``: a Universal Robots arm through ur-rtde, with the robot contract of ``sim_robot``.

Services ``move`` (RobotCommand -> RobotReply) and ``state``; outputs ``joint_state``, ``tcp_pose``
(T_base_tcp in ``base``) and ``frames`` (world -> base -> tcp), published at set-up and after every
command. A recipe switches between this stage and ``sim_robot`` by ``type:`` and parameters only.

Safety (docs/design.md): nothing moves on doubt. Before a move the stage checks the controller (connected,
safety mode NORMAL/REDUCED, no protective or emergency stop, arm RUNNING, control script running)
and the target (:mod:`plugins.devices.ur_motion_checks`: finite rigid pose, inside the workspace box,
within the step limits, speeds within the maxima); a failed check refuses the command with the
reason and the SDK's move functions are not called. Each ``command_id`` is executed at most once
(:mod:`plugins.devices.command_journal`); a repeat returns the first reply with ``duplicate=True``.

Moves are blocking; the engine never runs two handlers of a stage at once, so a ``stop`` command
cannot interrupt a move in progress (it decelerates the joints when idle and is harmless). Use the
pendant's stop or the safety system to stop a moving robot.

Poses: ``T`` in commands and replies is T_base_tcp in the UR *base* frame (PolyScope's Base view;
ROS drivers' ``base``, not ``base_link``), the TCP being the controller's active TCP (set it in
PolyScope). The SDK (``ur-rtde``: modules ``rtde_receive``, ``rtde_control``) is imported when the
stage is set up, not when vgr is imported.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np
from pydantic import Field, model_validator

from engine import transforms as tf
from engine.messages import FrameTransforms, JointState, PoseStamped, RobotCommand, RobotReply, Transform
from engine.stage import Stage, StageParams
from plugins.devices.command_journal import CommandJournal
from plugins.devices.ur_motion_checks import (
    MotionLimits,
    Workspace,
    joint_target_problem,
    pose_target_problem,
    resolve_rate,
)
from plugins.devices.ur_rtde_driver import URConnectionError, URDriver, URState
from plugins.interfaces import ROBOT_OUTPUTS, ROBOT_SERVICES
from plugins.params import PoseSpec
from plugins.util.sdk import import_sdk

IK_TOL_M, IK_TOL_RAD = 1e-5, math.radians(0.001)  # joints from the controller's IK must reach T this closely

# Hard maxima: a recipe cannot configure more than this (well below the UR controller's own limits).
HARD_MAX_LINEAR_SPEED_M_S = 1.0
HARD_MAX_LINEAR_ACCEL_M_S2 = 3.0
HARD_MAX_JOINT_SPEED_RAD_S = math.pi
HARD_MAX_JOINT_ACCEL_RAD_S2 = 10.0
JOINT_NAMES = [f"joint{i + 1}" for i in range(6)]  # the same names as sim_robot
BASE_FRAMES = ("", "base")

Vec3 = tuple[float, float, float]
Vec6 = tuple[float, float, float, float, float, float]


def _rate(default: float, hard_max: float, description: str) -> Any:
    """A speed or acceleration parameter: positive, and at most its hard maximum."""
    return Field(default, gt=0.0, le=hard_max, description=description)


class URRobotParams(StageParams):
    """Parameters of ``ur_robot`` (units in the names: m, deg, s, m/s, rad/s)."""

    ip: str = Field(description="IP address or host name of the UR controller")
    control: bool = Field(True, description="false: read-only (RTDE receive only, no script upload, moves refused)")
    workspace_min_m: Vec3 = Field(description="lower corner of the box TCP targets must lie in, base frame, m")
    workspace_max_m: Vec3 = Field(description="upper corner of the workspace box, base frame, m")
    max_step_m: float = Field(0.05, gt=0.0, le=2.0, description="largest TCP translation per command, m")
    max_step_deg: float = Field(15.0, gt=0.0, le=180.0, description="largest TCP rotation per command, deg")
    max_joint_step_deg: float = Field(30.0, gt=0.0, le=360.0, description="largest joint change per move_j, deg")
    joint_min_deg: Vec6 = Field((-360.0,) * 6, description="lower joint limits, deg")
    joint_max_deg: Vec6 = Field((360.0,) * 6, description="upper joint limits, deg")
    move_l_speed_m_s: float = _rate(
        0.05, HARD_MAX_LINEAR_SPEED_M_S, "TCP speed of move_l when the command gives 0, m/s"
    )
    move_l_speed_max_m_s: float = _rate(0.25, HARD_MAX_LINEAR_SPEED_M_S, "faster move_l commands are refused, m/s")
    move_l_accel_m_s2: float = _rate(
        0.25, HARD_MAX_LINEAR_ACCEL_M_S2, "TCP acceleration of move_l when the command gives 0, m/s^2"
    )
    move_l_accel_max_m_s2: float = _rate(
        1.2, HARD_MAX_LINEAR_ACCEL_M_S2, "larger move_l accelerations are refused, m/s^2"
    )
    move_j_speed_rad_s: float = _rate(
        0.25, HARD_MAX_JOINT_SPEED_RAD_S, "leading-joint speed of move_j by default, rad/s"
    )
    move_j_speed_max_rad_s: float = _rate(1.05, HARD_MAX_JOINT_SPEED_RAD_S, "faster move_j commands are refused, rad/s")
    move_j_accel_rad_s2: float = _rate(
        0.5, HARD_MAX_JOINT_ACCEL_RAD_S2, "leading-joint acceleration of move_j by default, rad/s^2"
    )
    move_j_accel_max_rad_s2: float = _rate(
        1.4, HARD_MAX_JOINT_ACCEL_RAD_S2, "larger move_j accelerations are refused, rad/s^2"
    )
    stop_deceleration_rad_s2: float = _rate(
        2.0, HARD_MAX_JOINT_ACCEL_RAD_S2, "joint deceleration of a stop command (stopJ), rad/s^2"
    )
    arrival_tolerance_m: float = Field(
        0.001, gt=0.0, description="after a move, farther than this from the target is reported as a failure, m"
    )
    arrival_tolerance_deg: float = Field(0.5, gt=0.0, description="the same for orientation and joints, deg")
    T_world_base: PoseSpec = Field(
        default_factory=PoseSpec, description="robot base in the world frame (published on frames)"
    )
    frequency_hz: float = Field(-1.0, description="RTDE frequency; -1 = the controller's (500 Hz e-Series, 125 CB3)")
    command_journal: str | None = Field(
        None, description="JSON-lines file of executed command ids; ids survive a restart (never re-executed)"
    )

    @model_validator(mode="after")
    def _consistent(self) -> URRobotParams:
        Workspace(self.workspace_min_m, self.workspace_max_m)  # raises on an empty or non-finite box
        pairs = [
            ("move_l_speed_m_s", "move_l_speed_max_m_s"),
            ("move_l_accel_m_s2", "move_l_accel_max_m_s2"),
            ("move_j_speed_rad_s", "move_j_speed_max_rad_s"),
            ("move_j_accel_rad_s2", "move_j_accel_max_rad_s2"),
        ]
        for default, maximum in pairs:
            if getattr(self, default) > getattr(self, maximum):
                raise ValueError(f"{default} ({getattr(self, default)}) exceeds {maximum} ({getattr(self, maximum)})")
        if any(lo >= hi for lo, hi in zip(self.joint_min_deg, self.joint_max_deg, strict=True)):
            raise ValueError("joint_min_deg must be below joint_max_deg for every joint")
        return self


class URRobot(Stage):
    """Universal Robots arm via ur-rtde: checked, idempotent moves; joint state and TCP pose."""

    type_name = "ur_robot"
    role = "device"
    services: ClassVar = ROBOT_SERVICES
    outputs: ClassVar = ROBOT_OUTPUTS
    Params = URRobotParams

    driver: URDriver | None = None

    def setup(self) -> None:
        p: URRobotParams = self.params  # type: ignore[assignment]
        self.limits = MotionLimits(
            workspace=Workspace(p.workspace_min_m, p.workspace_max_m),
            max_step_m=p.max_step_m,
            max_step_rad=math.radians(p.max_step_deg),
            max_joint_step_rad=math.radians(p.max_joint_step_deg),
            joint_min_rad=tuple(math.radians(v) for v in p.joint_min_deg),
            joint_max_rad=tuple(math.radians(v) for v in p.joint_max_deg),
        )
        self.journal = CommandJournal(p.command_journal)
        sdk = dict(stage_type=self.type_name, extra="ur", package="ur-rtde")
        rtde_receive = import_sdk("rtde_receive", **sdk)
        rtde_control = import_sdk("rtde_control", **sdk) if p.control else None
        self.driver = URDriver(p.ip, rtde_receive=rtde_receive, rtde_control=rtde_control, frequency_hz=p.frequency_hz)
        self._publish_state(self.driver.state())

    def halt(self) -> None:
        """The run stops early, or its data ends while a move is still served (its caller timed out):
        decelerate the joints (stopJ) at once, whatever command is running."""
        p: URRobotParams = self.params  # type: ignore[assignment]
        if self.driver is not None and p.control:
            self.driver.stop(p.stop_deceleration_rad_s2)

    def teardown(self) -> None:
        if self.driver is not None:
            self.driver.close()
            self.driver = None

    # -- services ------------------------------------------------------------------------------
    def on_request(self, service: str, request: Any) -> RobotReply:
        if service == "move":
            return self._command(request)
        return self._state_reply(str(getattr(request, "command", "")))

    def _state_reply(self, command_id: str, **kw: Any) -> RobotReply:
        state = self._try_state()
        if state is None:
            return RobotReply(command_id=command_id, ok=False, error=self._state_error, frame_id="base", **kw)
        return RobotReply(command_id=command_id, ok=True, frame_id="base", T=state.T_base_tcp, joints=state.q, **kw)

    def _command(self, cmd: RobotCommand) -> RobotReply:
        p: URRobotParams = self.params  # type: ignore[assignment]
        if cmd.kind == "state":
            return self._state_reply(cmd.command_id)
        if cmd.kind == "stop":
            assert self.driver is not None
            self.driver.stop(p.stop_deceleration_rad_s2)
            reply = self._state_reply(cmd.command_id)
            self._publish_after_command()
            return reply
        if not isinstance(cmd.command_id, str) or not cmd.command_id:
            return self._refused(cmd, "command_id must be a non-empty string (ids make commands idempotent)")
        known = self.journal.seen(cmd.command_id)
        if known is not None:
            first = self.journal.first_reply(cmd.command_id)
            if isinstance(first, RobotReply):
                return replace(first, duplicate=True, seq=0, stamp_ns=0)
            return self._refused(cmd, known.error, ok=known.ok, duplicate=True)
        self.journal.start(cmd.command_id)
        try:
            reply = self._execute(cmd)
        except Exception as exc:  # a link lost between checks, an SDK error: answer (and journal) it
            reply = self._refused(cmd, f"{cmd.kind}: {type(exc).__name__}: {exc}")
        self.journal.finish(cmd.command_id, reply.ok, reply.error, reply)
        self._publish_after_command()
        if not reply.ok:
            self.ctx.event("warning", "robot_refused", reply.error, command_id=cmd.command_id, kind=cmd.kind)
        return reply

    def _execute(self, cmd: RobotCommand) -> RobotReply:
        p: URRobotParams = self.params  # type: ignore[assignment]
        driver = self.driver
        assert driver is not None
        if cmd.frame_id not in BASE_FRAMES:
            return self._refused(cmd, f"target frame is {cmd.frame_id!r}; ur_robot takes T_base_tcp in 'base'")
        blocker = driver.motion_blocker()
        if blocker:
            return self._refused(cmd, blocker)
        now = driver.state()
        if cmd.kind == "move_l":
            speed, bad_speed = resolve_rate(cmd.speed, p.move_l_speed_m_s, p.move_l_speed_max_m_s, "speed", "m/s")
            accel, bad_accel = resolve_rate(
                cmd.acceleration, p.move_l_accel_m_s2, p.move_l_accel_max_m_s2, "acceleration", "m/s^2"
            )
        else:
            speed, bad_speed = resolve_rate(cmd.speed, p.move_j_speed_rad_s, p.move_j_speed_max_rad_s, "speed", "rad/s")
            accel, bad_accel = resolve_rate(
                cmd.acceleration, p.move_j_accel_rad_s2, p.move_j_accel_max_rad_s2, "acceleration", "rad/s^2"
            )
        if bad_speed or bad_accel:
            return self._refused(cmd, f"{cmd.kind}: {bad_speed or bad_accel}")

        target_T: np.ndarray | None = None
        target_q: np.ndarray | None = None
        if cmd.kind == "move_j" and cmd.joints is None and cmd.T is None:
            return self._refused(cmd, "move_j needs joints or a target pose T")
        if cmd.kind == "move_l" or cmd.joints is None:
            problem = pose_target_problem(cmd.T, now.T_base_tcp, self.limits)
            if problem:
                return self._refused(cmd, f"{cmd.kind}: {problem}")
            target_T = np.asarray(cmd.T, dtype=float)
        if cmd.kind == "move_l":
            assert target_T is not None
            move, target = driver.move_l, target_T
        else:
            if target_T is not None:  # move_j to a pose: the joints the controller's IK picks, checked first
                target_q = driver.inverse_kinematics(target_T, now.q)
                if target_q is None:
                    return self._refused(cmd, "move_j: the controller's inverse kinematics found no joints for T")
            else:
                target_q = np.asarray(cmd.joints, dtype=float)
            refusal = self._joint_target_refusal(target_q, now.q, target_T)
            if refusal:
                return self._refused(cmd, f"move_j: {refusal}")
            move, target = driver.move_j, target_q

        t0 = self.ctx.clock.now_s()
        try:
            done = move(target, speed, accel)
            sdk_error = ""
        except Exception as exc:  # the SDK raises RuntimeError/ValueError for controller-side problems
            done, sdk_error = False, f"ur-rtde raised {type(exc).__name__}: {exc}"
        duration = self.ctx.clock.now_s() - t0
        after = self._try_state()
        error = ""
        if not done:
            why = sdk_error or driver.motion_blocker() or "no fault visible; see the log on the teach pendant"
            error = f"{cmd.kind}: the controller did not complete the move ({why})"
        elif after is None:
            error = f"{cmd.kind}: the move returned but the state cannot be read ({self._state_error})"
        else:
            error = self._arrival_error(cmd.kind, after, target_T, target_q)
        return RobotReply(
            command_id=cmd.command_id,
            ok=not error,
            error=error,
            frame_id="base",
            T=None if after is None else after.T_base_tcp,
            joints=None if after is None else after.q,
            duration_s=duration,
        )

    def _joint_target_refusal(self, q: np.ndarray, q_now: np.ndarray, T_wanted: np.ndarray | None) -> str | None:
        """Why joint target *q* may not be commanded, or None: joint limits and step first, then its
        TCP by the controller's FK (inside the workspace; for a pose target, at that pose)."""
        problem = joint_target_problem(q, q_now, self.limits)
        if problem:
            return problem
        assert self.driver is not None
        T_fk = self.driver.forward_kinematics(q)
        if T_fk is None:
            return "the controller gave no TCP pose for the joint target (not moving)"
        outside = self.limits.workspace.outside_reason(T_fk[:3, 3], "TCP of the joint target")
        if outside:
            return outside
        if T_wanted is not None:
            d, a = tf.pose_error(T_fk, T_wanted)
            if d > IK_TOL_M or a > IK_TOL_RAD:
                return (
                    f"the inverse kinematics' joints reach {d * 1e3:.3f} mm / {math.degrees(a):.3f} deg from "
                    "the target pose (not moving)"
                )
        return None

    def _arrival_error(self, kind: str, s: URState, T: np.ndarray | None, q: np.ndarray | None) -> str:
        p: URRobotParams = self.params  # type: ignore[assignment]
        tol_rad = math.radians(p.arrival_tolerance_deg)
        if T is not None:
            dist, angle = tf.pose_error(s.T_base_tcp, T)
            if dist > p.arrival_tolerance_m or angle > tol_rad:
                return (
                    f"{kind}: the robot stopped {dist * 1000:.2f} mm / {math.degrees(angle):.3f} deg from the target "
                    f"(tolerance {p.arrival_tolerance_m * 1000:.2f} mm / {p.arrival_tolerance_deg} deg)"
                )
        if q is not None:
            dq = float(np.max(np.abs(s.q - q)))
            if dq > tol_rad:
                return f"{kind}: a joint stopped {math.degrees(dq):.3f} deg from the target"
        return ""

    def _refused(self, cmd: RobotCommand, reason: str, *, ok: bool = False, duplicate: bool = False) -> RobotReply:
        state = self._try_state()
        return RobotReply(
            command_id=cmd.command_id,
            ok=ok,
            error=reason,
            frame_id="base",
            T=None if state is None else state.T_base_tcp,
            joints=None if state is None else state.q,
            duplicate=duplicate,
        )

    # -- state ---------------------------------------------------------------------------------
    _state_error = ""

    def _try_state(self) -> URState | None:
        if self.driver is None:
            self._state_error = "the robot is not connected"
            return None
        try:
            return self.driver.state()
        except URConnectionError as exc:
            self._state_error = str(exc)
            return None

    def _publish_after_command(self) -> None:
        state = self._try_state()
        if state is not None:
            self._publish_state(state)

    def _publish_state(self, s: URState) -> None:
        p: URRobotParams = self.params  # type: ignore[assignment]
        self.ctx.publish("joint_state", JointState(names=list(JOINT_NAMES), positions=s.q.copy()))
        self.ctx.publish("tcp_pose", PoseStamped(T=s.T_base_tcp, frame_id="base"))
        self.ctx.publish(
            "frames",
            FrameTransforms(
                transforms=[
                    Transform(frame_id="world", child_frame_id="base", T=p.T_world_base.T()),
                    Transform(frame_id="base", child_frame_id="tcp", T=s.T_base_tcp),
                ]
            ),
        )
