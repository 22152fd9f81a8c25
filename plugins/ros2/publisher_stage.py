"""``ros2_publish``: a vgr port out to a ROS 2 topic, converted to a standard message type.

Wire any output to ``in`` and name the ROS 2 ``type`` and ``topic``::

    to_ros:
      type: ros2_publish
      inputs: {in: docking.correction}
      params:
        type: geometry_msgs/msg/PoseStamped
        topic: /vgr/correction
        frame_id: base_link
        tf_child_frame: vgr_correction

Each message is converted by :func:`plugins.ros2.convert.encode` (the conversions are listed in
docs/ros2.md). A :class:`~engine.messages.Correction` goes out as the pose of its ``T`` in
``frame_id`` — and only when its verdict is ``ok``: a refused correction is never passed on (an
``alarm`` event says so). ``tf_child_frame`` also publishes each pose or correction on ``/tf`` as
``frame_id -> tf_child_frame``.

The stage acts on the world outside the run (a ROS 2 robot driver may move on what it publishes),
so its role is ``device``: a replay never constructs it and publishes nothing.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.messages import Correction, FrameTransforms, Message, PoseStamped, Transform
from engine.stage import Stage, StageParams
from plugins.ros2 import node as ros_node
from plugins.ros2.qos import Qos, profile
from plugins.ros2.ros_types import ros_class

TF = "tf2_msgs/msg/TFMessage"


class Ros2PublishParams(StageParams):
    """Parameters of ``ros2_publish``."""

    ros: ros_node.RosSettings = Field(default_factory=ros_node.RosSettings, description="domain, discovery, namespace")
    type: str = Field(..., description="the ROS 2 message type, e.g. geometry_msgs/msg/PoseStamped")
    topic: str = Field(..., min_length=1, description="the topic to publish on")
    qos: Qos = Field("reliable", description="sensor_data, reliable, static or {reliability, durability, depth}")
    frame_id: str | None = Field(None, description="the ROS frame written into each header (unset: the message's)")
    tf_child_frame: str | None = Field(None, description="also publish poses and corrections on /tf as this frame")


class Ros2Publish(Stage):
    """A vgr port out to a ROS 2 topic (a refused correction is never published)."""

    type_name = "ros2_publish"
    role = "device"
    inputs: ClassVar = {"in": Message}
    Params = Ros2PublishParams

    def setup(self) -> None:
        from plugins.ros2.convert import SUPPORTED

        p: Ros2PublishParams = self.params  # type: ignore[assignment]
        if p.type not in SUPPORTED:
            raise ValueError(f"ros2_publish: type {p.type!r} is not one vgr converts ({', '.join(sorted(SUPPORTED))})")
        self.node = ros_node.acquire(p.ros, stage_type=self.type_name)
        self.publisher = self.node.publisher(ros_class(p.type), p.topic, profile(p.qos))
        self.tf = self.node.publisher(ros_class(TF), "/tf", profile("reliable")) if p.tf_child_frame else None
        self.sent = 0

    def _outgoing(self, msg: Message) -> Message | None:
        p: Ros2PublishParams = self.params  # type: ignore[assignment]
        if isinstance(msg, Correction):
            if msg.verdict != "ok":
                self.ctx.event("alarm", "correction_refused", f"not published on {p.topic}: verdict {msg.verdict}")
                return None
            msg = PoseStamped(T=np.asarray(msg.T), frame_id=msg.frame_id, stamp_ns=msg.stamp_ns)
        if p.frame_id is not None:
            msg = _with_frame(msg, p.frame_id)
        return msg

    def on_message(self, port: str, msg: Message) -> None:
        from plugins.ros2.convert import encode

        p: Ros2PublishParams = self.params  # type: ignore[assignment]
        out = self._outgoing(msg)
        if out is None:
            return
        self.publisher.publish(encode(out, p.type))
        self.sent += 1
        if self.tf is not None and isinstance(out, PoseStamped):
            edge = Transform(
                frame_id=out.frame_id, child_frame_id=p.tf_child_frame or "", T=out.T, stamp_ns=out.stamp_ns
            )
            self.tf.publish(encode(FrameTransforms(stamp_ns=out.stamp_ns, transforms=[edge]), TF))

    def finish(self) -> None:
        p: Ros2PublishParams = self.params  # type: ignore[assignment]
        self.ctx.event("info", "published", f"{self.sent} messages on {p.topic}", count=self.sent)

    def teardown(self) -> None:
        node = getattr(self, "node", None)
        if node is not None:
            for entity in (self.publisher, self.tf):
                if entity is not None:
                    node.destroy(entity)
            ros_node.release(node)


def _with_frame(msg: Message, frame_id: str) -> Any:
    """A copy of *msg* in the ROS frame *frame_id* (the received message is never changed)."""
    from dataclasses import replace

    return replace(msg, frame_id=frame_id)
