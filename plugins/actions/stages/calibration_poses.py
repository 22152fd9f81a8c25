"""``calibration_poses``: move the robot through calibration poses and sample the sensors at each.

The data collector of every calibration recipe. Per trigger it visits its targets in order:

* ``joints_deg``: listed joint configurations (``move_j``);
* ``random_joints``: ``count`` configurations drawn uniformly in ``ranges_deg`` from the stage's
  seeded generator (the same in a run and its replay; reachable: the ranges lie inside the limits);
* ``poses``: listed TCP poses ``T_frame_tcp`` in the frame ``frame`` (``T_base_frame``, e.g. the
  desk for Vive contacts), commanded as ``T_base_tcp = T_base_frame @ T_frame_tcp``;
* ``grid``: every point of ``points_m`` at every orientation of ``orientations_rpy_deg`` (fixture
  contacts: points x orientations), in ``frame``;
* ``pattern``: about a ``center`` pose, pure translations and rotations about the TCP (TCP
  calibration by camera, seed 002), in ``frame``.

At each target: ``move`` with command id ``<stage>-<trigger seq>-<k>`` (a replayed or repeated
trigger never moves twice), then each sensor named in ``sensors`` is read through its client:
``point`` (Request -> PoseStamped, e.g. ``sim_point_tracker.measure``), ``tracker`` (``sample``),
``camera`` (``capture``). Published per sample, all with the stamp of the first sensor reading (else the
robot's reply): ``joint_state``, ``tcp_pose`` (reported ``T_base_tcp``), ``target`` (the commanded
``T_frame_tcp`` in ``frame_id``: for a fixture contact, where the fixture holds the TCP) and the
sensor readings (``point``, ``tracker_pose``, ``cloud``, with their own stamps, or the sample's
when the device left its reading unstamped). After the last target, ``done`` (a Request ``solve``
with ``args`` ``samples`` of this sequence and ``total_samples`` so far) tells the solver stage to
calibrate once it has that many samples.

Safety: a repeated trigger (the robot answers ``duplicate``: it did not move) measures nothing; a
refused move or an unreachable robot raises an ``alarm`` event and stops the sequence at once,
without ``done`` (a solver with ``solve_on_finish`` still calibrates from the samples taken so far
when the run ends, and its verdict says whether they suffice); a failed sensor reading skips that
sample with a warning.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, ClassVar, Literal, cast

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial.transform import Rotation

from engine.messages import JointState, PointCloud, PoseStamped, Request, RobotCommand, RobotReply, TrackerPose
from engine.stage import ServiceError, ServiceSpec, Stage, StageParams
from engine.transforms import T_from_Rt
from plugins.interfaces import CAMERA_CAPTURE, ROBOT_MOVE, TRACKER_SAMPLE
from plugins.params import PoseSpec


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RandomJoints(_Strict):
    count: int = Field(ge=1, le=100_000)
    ranges_deg: tuple[tuple[float, float], ...] = Field(
        default=((-180.0, 180.0),) * 6, description="per joint [low, high], degrees"
    )

    @model_validator(mode="after")
    def _ordered(self) -> RandomJoints:
        for lo, hi in self.ranges_deg:
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"joint range [{lo}, {hi}] must be finite with low <= high")
        return self


class ContactGrid(_Strict):
    points_m: tuple[tuple[float, float, float], ...] = Field(min_length=1, description="TCP positions in `frame`")
    orientations_rpy_deg: tuple[tuple[float, float, float], ...] = Field(
        default=((0.0, 0.0, 0.0),), min_length=1, description="TCP orientations in `frame` (R = Rz Ry Rx)"
    )


class PosePattern(_Strict):
    center: PoseSpec = Field(description="T_frame_tcp of the centre pose")
    translations_m: tuple[tuple[float, float, float], ...] = Field(default=(), description="in `frame` axes")
    rotations_rpy_deg: tuple[tuple[float, float, float], ...] = Field(default=(), description="about the TCP")


def _R(rpy_deg: tuple[float, float, float]) -> np.ndarray:
    return Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()


class CalibrationPoses(Stage):
    """Moves through calibration poses; at each, reads the sensors (the data collector of calibrations)."""

    type_name = "calibration_poses"
    role = "action"
    inputs: ClassVar = {"trigger": Request}
    outputs: ClassVar = {
        "joint_state": JointState,
        "tcp_pose": PoseStamped,
        "target": PoseStamped,
        "point": PoseStamped,
        "tracker_pose": TrackerPose,
        "cloud": PointCloud,
        "done": Request,
    }
    uses: ClassVar = {
        "robot": ROBOT_MOVE,
        "point": ServiceSpec(Request, PoseStamped, "a point instrument's measure", optional=True),
        "tracker": ServiceSpec(TRACKER_SAMPLE.request, TRACKER_SAMPLE.reply, "a tracker's sample", optional=True),
        "camera": ServiceSpec(CAMERA_CAPTURE.request, CAMERA_CAPTURE.reply, "a camera's capture", optional=True),
    }

    class Params(StageParams):
        joints_deg: tuple[tuple[float, ...], ...] = Field(default=(), description="joint configurations")
        random_joints: RandomJoints | None = None
        poses: tuple[PoseSpec, ...] = Field(default=(), description="T_frame_tcp targets")
        grid: ContactGrid | None = None
        pattern: PosePattern | None = None
        frame: PoseSpec = Field(default_factory=PoseSpec, description="T_base_frame of pose targets")
        frame_id: str = Field("base", description="name of `frame` on the `target` messages")
        motion: Literal["move_j", "move_l"] = Field("move_j", description="how pose targets are approached")
        speed: float = Field(0.0, ge=0.0, description="0 = the robot's default")
        settle_s: float = Field(0.0, ge=0.0, le=60.0, description="wait after each move before sampling")
        timeout_s: float = Field(30.0, gt=0.0)
        sensors: tuple[Literal["point", "tracker", "camera"], ...] = Field(
            default=(), description="sensors read at each pose, in this order; each must be wired under `uses`"
        )

        @model_validator(mode="after")
        def _one_source(self) -> CalibrationPoses.Params:
            given = [
                n
                for n, v in (
                    ("joints_deg", self.joints_deg),
                    ("random_joints", self.random_joints),
                    ("poses", self.poses),
                    ("grid", self.grid),
                    ("pattern", self.pattern),
                )
                if v
            ]
            if len(given) != 1:
                raise ValueError(
                    "give exactly one of joints_deg, random_joints, poses, grid, pattern"
                    + (f" (got {', '.join(given)})" if given else "")
                )
            if self.joints_deg and len({len(q) for q in self.joints_deg}) != 1:
                raise ValueError("joints_deg: every configuration needs the same number of joints")
            return self

    def setup(self) -> None:
        p: CalibrationPoses.Params = self.params  # type: ignore[assignment]
        self.targets: list[tuple[str, np.ndarray]] = []  # ("joints", q rad) | ("pose", T_frame_tcp)
        if p.joints_deg:
            self.targets = [("joints", np.radians(q)) for q in p.joints_deg]
        elif p.random_joints is not None:
            r = np.radians(np.asarray(p.random_joints.ranges_deg, dtype=float))
            u = self.ctx.rng.random((p.random_joints.count, len(r)))
            self.targets = [("joints", r[:, 0] + row * (r[:, 1] - r[:, 0])) for row in u]
        elif p.poses:
            self.targets = [("pose", ps.T()) for ps in p.poses]
        elif p.grid is not None:
            self.targets = [
                ("pose", T_from_Rt(_R(o), pt)) for o in p.grid.orientations_rpy_deg for pt in p.grid.points_m
            ]
        elif p.pattern is not None:
            C = p.pattern.center.T()
            self.targets = [("pose", C)]
            self.targets += [("pose", T_from_Rt(C[:3, :3], C[:3, 3] + np.asarray(t))) for t in p.pattern.translations_m]
            self.targets += [("pose", C @ T_from_Rt(_R(o), np.zeros(3))) for o in p.pattern.rotations_rpy_deg]
        self.T_base_frame = p.frame.T()
        self.total_samples = 0  # samples published over all triggers (``done`` says it)

    # -- one sequence per trigger ------------------------------------------------------------
    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        p: CalibrationPoses.Params = self.params  # type: ignore[assignment]
        n_samples = 0
        for k, (kind, target) in enumerate(self.targets):
            cid = f"{self.ctx.name}-{msg.seq}-{k}"
            if kind == "joints":
                cmd = RobotCommand(command_id=cid, kind="move_j", joints=target, speed=p.speed, frame_id="base")
                T_frame_tcp = None
            else:
                T_frame_tcp = target
                cmd = RobotCommand(
                    command_id=cid, kind=p.motion, T=self.T_base_frame @ target, speed=p.speed, frame_id="base"
                )
            try:
                reply = cast(RobotReply, self.ctx.call("robot", cmd, timeout_s=p.timeout_s))
            except ServiceError as exc:
                self.ctx.event("alarm", "robot_unavailable", f"pose {k}: {exc}; calibration sequence stopped", pose=k)
                return
            if not reply.ok:
                self.ctx.event(
                    "alarm",
                    "robot_refused",
                    f"move to calibration pose {k} refused: {reply.error}; calibration sequence stopped",
                    pose=k,
                    command_id=cid,
                )
                return
            if reply.duplicate:  # this trigger was handled before: the robot did not move, measure nothing
                self.ctx.event("warning", "duplicate_trigger", f"command {cid} was already executed; sequence skipped")
                return
            if p.settle_s and not self.ctx.sleep(p.settle_s):
                return
            if self._sample(k, reply, T_frame_tcp):
                n_samples += 1
                self.total_samples += 1
        done = {"samples": n_samples, "total_samples": self.total_samples, "trigger_seq": msg.seq}
        self.ctx.publish("done", Request(command="solve", args=done))

    def _read(self, client: str, k: int) -> Any:
        p: CalibrationPoses.Params = self.params  # type: ignore[assignment]
        if client not in p.sensors:
            return None
        command = {"point": "measure", "tracker": "sample", "camera": "capture"}[client]
        try:
            return self.ctx.call(client, Request(command=command), timeout_s=p.timeout_s)
        except ServiceError as exc:
            self.ctx.event("warning", "sensor_failed", f"pose {k}: {client} reading failed ({exc}); sample skipped")
            raise

    def _sample(self, k: int, reply: RobotReply, T_frame_tcp: np.ndarray | None) -> bool:
        p: CalibrationPoses.Params = self.params  # type: ignore[assignment]
        try:
            readings = {c: self._read(c, k) for c in ("point", "tracker", "camera")}
        except ServiceError:
            return False
        stamps = [r.stamp_ns for r in readings.values() if r is not None and r.stamp_ns]
        stamp = stamps[0] if stamps else int(reply.stamp_ns)
        joints = np.asarray(reply.joints if reply.joints is not None else [], dtype=float)
        names = [f"joint{i + 1}" for i in range(len(joints))]
        self.ctx.publish("joint_state", JointState(names=names, positions=joints, stamp_ns=stamp))
        if reply.T is not None:
            self.ctx.publish("tcp_pose", PoseStamped(T=reply.T, frame_id="base", stamp_ns=stamp))
        if T_frame_tcp is not None:
            self.ctx.publish("target", PoseStamped(T=T_frame_tcp, frame_id=p.frame_id, stamp_ns=stamp))
        for client, port in (("point", "point"), ("tracker", "tracker_pose"), ("camera", "cloud")):
            reading = readings[client]
            if reading is not None:  # a device that does not stamp its readings gets the sample's stamp
                self.ctx.publish(port, reading if reading.stamp_ns else replace(reading, stamp_ns=stamp))
        return True
