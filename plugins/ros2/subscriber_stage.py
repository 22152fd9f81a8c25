"""``ros2_subscribe``: ROS 2 topics into vgr ports, as a source stage.

Each output port takes one topic, converted by :func:`plugins.ros2.convert.decode`::

    from_ros:
      type: ros2_subscribe
      params:
        ros: {domain_id: 3, discovery: localhost}
        topics:
          cloud: {topic: /camera/depth/points, qos: sensor_data}
          joint_state: {topic: /joint_states}
          frames: {topic: /tf_static, qos: static}
        frames: {camera_depth_optical_frame: camera}    # ROS frame ids -> vgr frame names
        max_messages: 300                                # end after this many (unset: run until stopped)

Ports: ``cloud`` (PointCloud2), ``image`` (Image), ``camera_info`` (CameraInfo), ``joint_state``
(JointState), ``pose`` (PoseStamped), ``frames`` (TFMessage, for ``/tf`` and ``/tf_static``).
A message keeps its header's stamp (ROS time, nanoseconds). Each message is converted and
published on the ROS 2 executor's thread as it arrives (the node's single-threaded executor: one
at a time, in arrival order), with no hand-over to another thread: in one
trial of benchmarks/ros2_bridge.py (1.2 MB clouds, publisher flat out, loaded 2-core machine) a
hand-over to the stage's own thread took 51.8 clouds a second against a plain rclpy subscriber's
106 (docs/ros2.md has the full run). ``run`` only waits for the end (``max_messages``,
``duration_s``, the run's stop); the topics are subscribed when ``run`` starts, and a message
arriving after it ends is not published. A message that does not convert is an ``error`` event
naming the topic and the field, and the stream goes on; the DDS reader's history (the topic's QoS
``depth``) is the only queue.

A source: replay feeds its outputs from the recording and never constructs it.
"""

from __future__ import annotations

import threading
import time
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, field_validator

from engine.messages import CameraInfo, FrameTransforms, Image, JointState, PointCloud, PoseStamped
from engine.stage import Stage, StageParams
from plugins.ros2 import node as ros_node
from plugins.ros2.qos import Qos, profile
from plugins.ros2.ros_types import ros_class

PORT_TYPES = {  # output port -> (vgr type, ROS 2 type)
    "cloud": (PointCloud, "sensor_msgs/msg/PointCloud2"),
    "image": (Image, "sensor_msgs/msg/Image"),
    "camera_info": (CameraInfo, "sensor_msgs/msg/CameraInfo"),
    "joint_state": (JointState, "sensor_msgs/msg/JointState"),
    "pose": (PoseStamped, "geometry_msgs/msg/PoseStamped"),
    "frames": (FrameTransforms, "tf2_msgs/msg/TFMessage"),
}
POLL_S = 0.1  # run() looks at ctx.stopping this often while no message comes


class TopicSpec(BaseModel):
    """One subscribed topic."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    topic: str = Field(..., min_length=1)
    qos: Qos = "reliable"


class Ros2SubscribeParams(StageParams):
    """Parameters of ``ros2_subscribe``."""

    ros: ros_node.RosSettings = Field(default_factory=ros_node.RosSettings, description="domain, discovery, namespace")
    topics: dict[str, TopicSpec] = Field(
        ..., min_length=1, description=f"output port -> topic; ports: {list(PORT_TYPES)}"
    )
    frames: dict[str, str] | None = Field(None, description="ROS frame id -> vgr frame name (unset: names kept)")
    max_messages: int | None = Field(
        None, ge=1, description="end after this many messages in all (unset: until stopped)"
    )
    duration_s: float | None = Field(None, gt=0.0, description="end after this long (unset: until stopped)")

    @field_validator("topics")
    @classmethod
    def _known_ports(cls, topics: dict[str, TopicSpec]) -> dict[str, TopicSpec]:
        unknown = sorted(set(topics) - set(PORT_TYPES))
        if unknown:
            raise ValueError(f"no output port {unknown} (ports: {', '.join(PORT_TYPES)})")
        return topics


class Ros2Subscribe(Stage):
    """ROS 2 topics into vgr ports (a source: converted and published in arrival order)."""

    type_name = "ros2_subscribe"
    role = "source"
    outputs: ClassVar = {port: cls for port, (cls, _) in PORT_TYPES.items()}
    Params = Ros2SubscribeParams

    def setup(self) -> None:
        p: Ros2SubscribeParams = self.params  # type: ignore[assignment]
        self._lock = threading.Lock()  # held while a message is converted and published
        self._open = False  # True while run() runs: no message is published before it or after it
        self._ended = threading.Event()
        self._fault: BaseException | None = None
        self.received = self.failed = 0
        self.node = ros_node.acquire(p.ros, stage_type=self.type_name)
        self.classes = {port: ros_class(PORT_TYPES[port][1]) for port in p.topics}  # a missing package fails here
        self.subscriptions: list[Any] = []

    def _taker(self, port: str) -> Any:
        from plugins.ros2.convert import ConversionError, decode

        p: Ros2SubscribeParams = self.params  # type: ignore[assignment]
        msgtype, topic, frames = PORT_TYPES[port][1], p.topics[port].topic, p.frames

        def take(data: bytes) -> None:  # on the executor thread
            with self._lock:
                if not self._open:
                    return
                self.received += 1
                try:
                    self.ctx.publish(port, decode(msgtype, data, topic=topic, frames=frames))
                except ConversionError as exc:
                    self.failed += 1
                    self.ctx.event("error", "ros2_conversion", str(exc), topic=topic)
                except BaseException as exc:
                    self._fault, self._open = exc, False
                    self._ended.set()
                    return
                if p.max_messages is not None and self.received >= p.max_messages:
                    self._open = False
                    self._ended.set()

        return take

    def run(self) -> None:
        p: Ros2SubscribeParams = self.params  # type: ignore[assignment]
        end = None if p.duration_s is None else time.monotonic() + p.duration_s
        with self._lock:
            self._open = True
        for port, spec in p.topics.items():  # subscribed now: the run is under way, what comes is published
            self.subscriptions.append(
                self.node.subscribe_raw(self.classes[port], spec.topic, profile(spec.qos), self._taker(port))
            )
        while not self.ctx.stopping and not self._ended.wait(POLL_S):
            if end is not None and time.monotonic() >= end:
                break
        with self._lock:  # a callback under way finishes first; none publishes after this
            self._open = False
        if self._fault is not None:
            raise self._fault
        self.ctx.event(
            "result",
            "received",
            f"{self.received} ROS 2 messages, {self.failed} not convertible",
            received=self.received,
            failed=self.failed,
        )

    def teardown(self) -> None:
        node = getattr(self, "node", None)
        if node is not None:
            for sub in self.subscriptions:
                node.destroy(sub)
            ros_node.release(node)
