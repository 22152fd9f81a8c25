"""``measurement_campaign``: drive the robot through poses and measure the tool with a tracker (action).

For each trigger: ``n_poses`` joint moves (random configurations within the joint ranges given, from
the stage's seeded generator, or the explicit ``poses_deg``), and after each arrival one tracker
reading (``tracker.sample``), published on ``measurement``. With the robot's ``joint_state`` stream
this is the data the ``model_gap`` stage (and ``vgr gap`` on the recording) analyses. Command ids
are ``<stage>-<trigger seq>-<i>``, so a replayed or repeated trigger never moves the robot twice. A
refused move raises a ``warning`` event and skips that pose; so does a reply that is not a fresh
arrival (a ``duplicate`` command id, no joints) and a tracker reading stamped before the arrival
(each measurement is published only with the joints it was taken at); a lost reading is skipped.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field, model_validator

from engine.messages import JointState, Request, RobotCommand, TrackerPose
from engine.stage import ServiceError, Stage, StageParams
from plugins.interfaces import ROBOT_MOVE, TRACKER_SAMPLE


class MeasurementCampaign(Stage):
    """Moves through poses (random or listed) and publishes a tracker reading at each."""

    type_name = "measurement_campaign"
    role = "action"
    inputs: ClassVar = {"trigger": Request}
    outputs: ClassVar = {"measurement": TrackerPose, "joint_state": JointState}
    uses: ClassVar = {"robot": ROBOT_MOVE, "tracker": TRACKER_SAMPLE}

    class Params(StageParams):
        n_poses: int = Field(60, ge=1, le=100_000, description="random poses per trigger (ignored with poses_deg)")
        lower_deg: tuple[float, ...] = Field((-170.0,), description="lower joint bound (one value or one per joint)")
        upper_deg: tuple[float, ...] = Field((170.0,), description="upper joint bound (one value or one per joint)")
        poses_deg: list[tuple[float, ...]] | None = Field(None, description="explicit joint poses (deg)")
        dof: int = Field(6, ge=1, le=12)
        speed: float = Field(0.0, ge=0.0, description="joint speed rad/s, 0 = the robot's default")
        timeout_s: float = Field(60.0, gt=0.0)

        @model_validator(mode="after")
        def _check(self) -> MeasurementCampaign.Params:
            for name in ("lower_deg", "upper_deg"):
                v = getattr(self, name)
                if len(v) not in (1, self.dof) or not np.all(np.isfinite(v)):
                    raise ValueError(f"{name} needs 1 or {self.dof} finite values")
            if np.any(np.broadcast_to(self.lower_deg, self.dof) >= np.broadcast_to(self.upper_deg, self.dof)):
                raise ValueError("lower_deg must be below upper_deg")
            for p in self.poses_deg or []:
                if len(p) != self.dof or not np.all(np.isfinite(p)):
                    raise ValueError(f"every pose needs {self.dof} finite joint angles")
            return self

    def _poses(self) -> np.ndarray:
        p: MeasurementCampaign.Params = self.params  # type: ignore[assignment]
        if p.poses_deg:
            return np.radians(np.array(p.poses_deg, dtype=float))
        lo = np.radians(np.broadcast_to(p.lower_deg, p.dof))
        hi = np.radians(np.broadcast_to(p.upper_deg, p.dof))
        return lo + self.ctx.rng.random((p.n_poses, p.dof)) * (hi - lo)

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        p: MeasurementCampaign.Params = self.params  # type: ignore[assignment]
        measured = 0
        last_stamp = 0
        for i, q in enumerate(self._poses()):
            cmd = RobotCommand(command_id=f"{self.ctx.name}-{msg.seq}-{i}", kind="move_j", joints=q, speed=p.speed)
            try:
                reply = self.ctx.call("robot", cmd, timeout_s=p.timeout_s)
            except ServiceError as exc:
                self.ctx.event("alarm", "robot_unavailable", str(exc))
                return
            if not reply.ok:
                self.ctx.event("warning", "pose_refused", f"pose {i} refused: {reply.error}")
                continue
            if reply.duplicate or reply.joints is None:  # no arrival now, or none to pair the reading with
                why = "a repeated command id: the robot did not move now" if reply.duplicate else "no joints"
                self.ctx.event("warning", "pose_unpaired", f"pose {i} skipped: the move reply has {why}")
                continue
            reading = self.ctx.call("tracker", Request(command="sample"), timeout_s=p.timeout_s)
            if not reading.valid:
                continue
            if reading.stamp_ns and reply.stamp_ns and reading.stamp_ns < reply.stamp_ns:
                self.ctx.event(
                    "warning",
                    "stale_reading",
                    f"pose {i} skipped: the tracker reading is {(reply.stamp_ns - reading.stamp_ns) / 1e6:.1f} ms "
                    "older than the robot's arrival (it was taken before the pose was reached)",
                )
                continue
            # the reading's own time, else the robot's or ours; strictly increasing (>= 1 ms apart) so the
            # joints and the reading of one pose pair one to one even when the clocks did not move
            stamp = max(reading.stamp_ns or 0, reply.stamp_ns or 0, self.ctx.clock.now_ns(), last_stamp + 1_000_000)
            last_stamp = stamp
            self.ctx.publish(
                "measurement",
                TrackerPose(stamp_ns=stamp, frame_id=reading.frame_id, serial=reading.serial, T=np.array(reading.T)),
            )
            joints = np.asarray(reply.joints, dtype=float)
            names = [f"joint{j + 1}" for j in range(joints.size)]
            self.ctx.publish(
                "joint_state",
                JointState(names=names, positions=joints, velocities=np.zeros_like(joints), stamp_ns=stamp),
            )
            measured += 1
        self.ctx.event("info", "campaign_done", f"{measured} measurements", n=measured)
