"""``sim_robot``: the simulated robot controller as a device stage (robot contract + ground truth).

Wraps :class:`plugins.sim.controller.SimRobotController`. Moves take simulated time (the run's
clock sleeps through them: instantly on the ``sim`` clock, really on the ``wall`` clock). The
reported pose is the nominal model's, as a real controller reports from its encoders; where the
TCP truly is (robot effects: DH errors, compliance, backlash, eccentricity, thermal drift, TCP
offset) is given only by the ``truth`` service and the ``truth/tcp_pose`` port.

State streams (``joint_state``, ``tcp_pose``, ``frames`` and ``truth/tcp_pose``, one message each
per sample): at set-up, during every move at ``state_rate_hz`` of the run's clock, and once at rest
after the move. The samples of a move fall at ``t0 + k / state_rate_hz`` (``t0`` = when the
command was accepted, integer ns; ``k = 1, 2, ...`` while the robot is still moving) and each is
the controller's motion profile evaluated at its stamp, so a move of ``d`` seconds publishes
``ceil(d * state_rate_hz)`` samples including the one at rest (on the ``sim`` clock exactly; on the
``wall`` clock a late wake-up samples later, at the time it reads). ``state_rate_hz: 0`` publishes
at set-up and at rest only.

``halt()`` (the run stops early: Ctrl-C, a failed stage; or its data ends while a move is still
being served, as after a move whose caller timed out) stops the move in progress on its path, as a
controller's stop does: the controller decelerates at the move's own acceleration and the move ends
where the robot comes to rest (an ``info`` event ``move_halted`` says which command and where); the
move's reply, if its caller still waits, is ``ok: false`` with ``error: halted ...``.
"""

from __future__ import annotations

import math
import threading
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.messages import FrameTransforms, JointState, PoseStamped, Request, RobotCommand, RobotReply, Transform
from engine.stage import ServiceSpec, Stage, StageParams
from plugins.interfaces import ROBOT_OUTPUTS, ROBOT_SERVICES
from plugins.params import PoseSpec
from plugins.robot.effects import effect_from_config
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects
from plugins.sim import controller as ctl


class SimRobot(Stage):
    """Simulated robot controller: move/state services, joint state and TCP pose, ground truth."""

    type_name = "sim_robot"
    role = "device"
    services: ClassVar = {
        **ROBOT_SERVICES,
        "truth": ServiceSpec(Request, RobotReply, "TRUE T_world_tcp and joints (simulation ground truth)"),
    }
    outputs: ClassVar = {**ROBOT_OUTPUTS, "truth/tcp_pose": PoseStamped}

    class Params(StageParams):
        model: str = Field("ur5e", description="shipped model name (ur5e, abb_irb120) or a model file path")
        q_initial_deg: tuple[float, ...] | None = Field(None, description="initial joints, degrees (default: home)")
        T_world_base: PoseSpec = Field(default_factory=PoseSpec, description="robot base in the world frame")
        T_flange_tcp: PoseSpec | None = Field(None, description="tool (TCP) on the flange; default: the model's")
        effects: dict[str, dict[str, Any]] = Field(
            default_factory=dict, description="robot effects by catalog name (all off by default)"
        )
        payload_kg: float = Field(0.0, ge=0.0)
        move_l_speed_m_s: float = Field(ctl.MOVEL_SPEED, gt=0.0, le=2.0)
        move_l_accel_m_s2: float = Field(ctl.MOVEL_ACCEL, gt=0.0, le=20.0)
        move_j_speed_rad_s: float = Field(ctl.MOVEJ_SPEED, gt=0.0, le=6.0)
        move_j_accel_rad_s2: float = Field(ctl.MOVEJ_ACCEL, gt=0.0, le=40.0)
        state_rate_hz: float = Field(
            25.0, ge=0.0, le=1000.0, description="state samples per second during a move (run clock); 0 = at rest only"
        )

    def setup(self) -> None:
        p: SimRobot.Params = self.params  # type: ignore[assignment]
        nominal = load_robot_model(p.model).with_base(p.T_world_base.T())
        if p.T_flange_tcp is not None:
            nominal = nominal.with_tool(p.T_flange_tcp.T())
        effects = [effect_from_config(name, cfg) for name, cfg in p.effects.items()]
        self.true_robot = RobotWithEffects(nominal, effects)
        q0 = None if p.q_initial_deg is None else np.radians(p.q_initial_deg)
        self.ctl = ctl.SimRobotController(
            nominal, clock=self.ctx.clock.now_s, true_robot=self.true_robot, q_initial=q0, payload_kg=p.payload_kg
        )
        self.nominal = nominal
        self._halt_requested = threading.Event()  # set by halt(): a move being followed ends at rest
        self._publish_state()

    # -- services ------------------------------------------------------------------------------
    def on_request(self, service: str, request: Any) -> RobotReply:
        if service == "move":
            return self._move(request)
        state = self.ctl.state()
        if service == "truth":
            return RobotReply(
                command_id="truth", ok=True, frame_id="world", T=state.T_world_tcp_actual, joints=state.q_actual
            )
        return RobotReply(
            command_id=str(getattr(request, "command", "")),
            ok=True,
            frame_id="base",
            T=state.T_base_tcp,
            joints=state.q,
        )

    def _move(self, cmd: RobotCommand) -> RobotReply:
        p: SimRobot.Params = self.params  # type: ignore[assignment]
        t0_ns = self.ctx.clock.now_ns()
        if cmd.kind == "stop" or cmd.kind == "state":
            state = self.ctl.state()
            return RobotReply(command_id=cmd.command_id, ok=True, frame_id="base", T=state.T_base_tcp, joints=state.q)
        if cmd.kind == "move_l":
            if cmd.T is None:
                return self._refused(cmd, "move_l needs a target pose T (T_base_tcp)")
            res = self.ctl.move_l(
                cmd.command_id,
                cmd.T,
                speed=cmd.speed or p.move_l_speed_m_s,
                accel=cmd.acceleration or p.move_l_accel_m_s2,
            )
        elif cmd.joints is not None or cmd.T is not None:  # move_j to joints, or to a pose through IK
            move_j = self.ctl.move_j if cmd.joints is not None else self.ctl.move_j_pose
            res = move_j(
                cmd.command_id,
                cmd.joints if cmd.joints is not None else cmd.T,
                speed=cmd.speed or p.move_j_speed_rad_s,
                accel=cmd.acceleration or p.move_j_accel_rad_s2,
            )
        else:
            return self._refused(cmd, "move_j needs joints or a target pose T")
        if res.accepted and not res.duplicate:
            self._follow(t0_ns, res.duration_s)  # the motion takes (simulated) time
            res = self.ctl.result(cmd.command_id) or res  # (halted meanwhile: it ends early, at rest)
            self._arrive(res.end_s)
            res = self.ctl.result(cmd.command_id) or res  # (halted meanwhile: it ended early)
        state = self.ctl.state()
        if res.accepted and not res.duplicate:
            self._publish_state()
        halted = "halted before its target: the run stopped" if res.halted else ""
        return RobotReply(
            command_id=cmd.command_id,
            ok=res.accepted and not res.halted,
            error=halted or ("" if res.accepted else res.reason),
            frame_id="base",
            T=state.T_base_tcp,
            joints=state.q,
            duration_s=res.duration_s,
            duplicate=res.duplicate,
            stamp_ns=self.ctx.clock.now_ns(),
        )

    def halt(self) -> None:
        """Stop the move in progress now, on its path (see the module docstring)."""
        controller: ctl.SimRobotController | None = getattr(self, "ctl", None)  # None: stopped before setup
        if controller is None or (res := controller.halt()) is None:
            return
        self._halt_requested.set()
        q_rest = np.degrees(controller.state(res.end_s).q)
        self.ctx.event(
            "info",
            "move_halted",
            f"move {res.command_id} halted, at rest {res.end_s - controller.clock():.3f} s later, "
            f"joints {np.array2string(q_rest, precision=2)} deg",
            command_id=res.command_id,
            q_rest_deg=q_rest.tolist(),
        )

    def _refused(self, cmd: RobotCommand, reason: str) -> RobotReply:
        state = self.ctl.state()
        return RobotReply(
            command_id=cmd.command_id, ok=False, error=reason, frame_id="base", T=state.T_base_tcp, joints=state.q
        )

    def _arrive(self, end_s: float) -> None:
        """Sleep until the move has ended. The controller's times are float64 seconds since the
        clock's epoch (~0.2 us apart at today's epoch), so the clock may land a step short of the
        end: it is then moved on by a microsecond, at most a few times."""
        self.ctx.sleep(max(0.0, end_s - self.ctx.clock.now_s()))
        for _ in range(5):
            if not self.ctl.is_moving() or not self.ctx.sleep(1e-6):
                return

    # -- streams -------------------------------------------------------------------------------
    def _follow(self, t0_ns: int, duration_s: float) -> None:
        """Publish the state along a move at ``state_rate_hz``, sleeping from sample to sample."""
        rate = self.params.state_rate_hz  # type: ignore[attr-defined]
        if rate <= 0:
            return
        end_ns = t0_ns + round(duration_s * 1e9)
        k = 1
        while (tick_ns := t0_ns + round(k * 1e9 / rate)) < end_ns:
            if not self.ctx.sleep(max(0, tick_ns - self.ctx.clock.now_ns()) / 1e9) or self._halt_requested.is_set():
                return  # the run is stopping, or the move was halted
            now_ns = self.ctx.clock.now_ns()
            if now_ns >= end_ns:
                return
            self._publish_state(now_ns)
            k = max(k + 1, math.floor((now_ns - t0_ns) * rate / 1e9) + 1)  # a late wake-up skips samples

    def _publish_state(self, stamp_ns: int | None = None) -> None:
        """State streams, stamped with the time of the state (a device reports measurements)."""
        now = self.ctx.clock.now_ns() if stamp_ns is None else stamp_ns
        s = self.ctl.state(now / 1_000_000_000)  # int / int: the clock's own now_s(), correctly rounded
        names = [f"joint{i + 1}" for i in range(len(s.q))]
        self.ctx.publish("joint_state", JointState(names=names, positions=s.q, velocities=s.qd, stamp_ns=now))
        self.ctx.publish("tcp_pose", PoseStamped(T=s.T_base_tcp, frame_id="base", stamp_ns=now))
        tree = [
            Transform(frame_id="world", child_frame_id="base", T=self.nominal.T_world_base, stamp_ns=now),
            Transform(frame_id="base", child_frame_id="tcp", T=s.T_base_tcp, stamp_ns=now),
        ]
        self.ctx.publish("frames", FrameTransforms(stamp_ns=now, transforms=tree))
        self.ctx.publish("truth/tcp_pose", PoseStamped(T=s.T_world_tcp_actual, frame_id="world", stamp_ns=now))
