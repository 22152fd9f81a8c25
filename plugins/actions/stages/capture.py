"""``capture_at_pose``: move the robot to a taught photo pose and capture a cloud (an action stage).

For each trigger: ``move`` (joint move to the photo pose by default; command id
``<stage>-<trigger seq>`` so a replayed or repeated trigger never moves twice), then ``capture``.
Outputs the cloud (camera frame) and the TCP pose it was taken at. A refused move or a failed
capture raises an ``alarm`` event and publishes nothing (no capture from an unknown pose).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from engine.messages import PointCloud, PoseStamped, Request
from engine.stage import ServiceError, Stage, StageParams
from plugins.actions import robot_moves
from plugins.interfaces import CAMERA_CAPTURE, ROBOT_MOVE
from plugins.params import PoseSpec


class CaptureAtPose(Stage):
    """Moves to the photo pose (T_base_tcp) and captures; publishes the cloud and the pose."""

    type_name = "capture_at_pose"
    role = "action"
    inputs: ClassVar = {"trigger": Request}
    outputs: ClassVar = {"cloud": PointCloud, "pose": PoseStamped}
    uses: ClassVar = {"robot": ROBOT_MOVE, "camera": CAMERA_CAPTURE}

    class Params(StageParams):
        photo_pose: PoseSpec = Field(description="T_base_tcp of the photo pose")
        motion: Literal["move_j", "move_l"] = "move_j"
        speed: float = Field(0.0, ge=0.0, description="0 = the robot's default")
        timeout_s: float = Field(30.0, gt=0.0)

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        p: CaptureAtPose.Params = self.params  # type: ignore[assignment]
        try:  # the shared move: refused, unanswered and already-handled ('duplicate') commands raise
            reply = robot_moves.move(
                self.ctx, f"{self.ctx.name}-{msg.seq}", p.photo_pose.T(), p.motion, speed=p.speed, timeout_s=p.timeout_s
            )
        except robot_moves.MoveRefused as exc:
            self.ctx.event("alarm", exc.code, f"move to the photo pose: {exc}")
            return
        try:
            cloud = self.ctx.call("camera", Request(command="capture"), timeout_s=p.timeout_s)
        except ServiceError as exc:
            self.ctx.event("alarm", "capture_failed", str(exc))
            return
        self.ctx.publish("cloud", cloud)
        self.ctx.publish("pose", PoseStamped(T=reply.T, frame_id="base"))
