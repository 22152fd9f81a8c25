"""``ros2_camera``: a ROS 2 depth camera driver's ``sensor_msgs/PointCloud2`` topic as a vgr depth
camera (the camera contract of plugins.interfaces).

The stage subscribes to ``topic`` (QoS ``sensor_data`` by default: camera drivers publish best
effort) and keeps only the latest message, undecoded (:mod:`plugins.ros2.inbox`). ``capture``
answers with the first cloud that **arrives after the request** (after ``skip_frames`` more: a
cloud exposed while the robot was still moving is never taken), waiting up to ``timeout_s`` (or the
request's ``{"timeout_s": ...}``); it is converted then (:func:`plugins.ros2.convert.decode`), its
non-finite points dropped, and published like every camera's capture
(:func:`plugins.devices.camera_output.publish_capture`: ``cloud``, ``frames`` with the mount).

Frames: the cloud is in vgr's ``frame_id`` (default ``camera``); ``ros_frame_id`` names the ROS
frame the driver stamps (e.g. ``camera_depth_optical_frame``) and a cloud in any other frame is
refused, naming the topic and ``header.frame_id``. Like every capture the cloud carries the run's
time of the request (a replay reproduces it), not the driver's header stamp.

Replay feeds this stage's outputs and replies from the recording and never constructs it: a
recording made in a ROS 2 cell replays on a machine without ROS 2.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from engine.messages import PointCloud
from plugins.devices.camera_output import (
    CameraFrame,
    DepthCameraAdapter,
    DepthCameraParams,
    publish_capture,
    publish_mount,
)
from plugins.ros2 import node as ros_node
from plugins.ros2.inbox import Inbox
from plugins.ros2.qos import Qos, profile
from plugins.ros2.ros_types import ros_class

CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"


class Ros2CameraParams(DepthCameraParams):
    """Parameters of ``ros2_camera``."""

    ros: ros_node.RosSettings = Field(default_factory=ros_node.RosSettings, description="domain, discovery, namespace")
    topic: str = Field(..., min_length=1, description="the PointCloud2 topic, e.g. /camera/depth/color/points")
    qos: Qos = Field("sensor_data", description="sensor_data, reliable, static or {reliability, durability, depth}")
    ros_frame_id: str | None = Field(None, description="the ROS frame the clouds must be in (unset: any)")
    timeout_s: float = Field(5.0, gt=0.0, le=600.0, description="longest wait for a cloud after a capture request, s")
    skip_frames: int = Field(0, ge=0, le=100, description="clouds to let pass after the request before taking one")


class Ros2Camera(DepthCameraAdapter):
    """A ROS 2 PointCloud2 topic as a depth camera: capture takes the next cloud that arrives."""

    type_name = "ros2_camera"
    Params = Ros2CameraParams

    def setup(self) -> None:
        p: Ros2CameraParams = self.params  # type: ignore[assignment]
        self.inbox = Inbox(p.topic)
        self.node = ros_node.acquire(p.ros, stage_type=self.type_name)
        self.subscription = self.node.subscribe_raw(ros_class(CLOUD_TYPE), p.topic, profile(p.qos), self.inbox.put)
        publish_mount(self.ctx, p)

    def on_request(self, service: str, request: Any) -> PointCloud:
        from plugins.ros2.convert import ConversionError, decode

        p: Ros2CameraParams = self.params  # type: ignore[assignment]
        timeout_s = float(getattr(request, "args", {}).get("timeout_s", p.timeout_s))
        received = self.inbox.fresh(timeout_s, skip=p.skip_frames)
        cloud = decode(CLOUD_TYPE, received.data, topic=p.topic)
        assert isinstance(cloud, PointCloud)
        if p.ros_frame_id is not None and cloud.frame_id != p.ros_frame_id:
            raise ConversionError(
                f"topic {p.topic!r}: header.frame_id is {cloud.frame_id!r}, "
                f"the recipe's ros_frame_id is {p.ros_frame_id!r}"
            )
        keep = np.isfinite(cloud.points).all(axis=1)
        frame = CameraFrame(
            points=cloud.points[keep],
            normals=None if cloud.normals is None else cloud.normals[keep],
            colors=None if cloud.colors is None else cloud.colors[keep],
            source=f"{p.topic} #{received.number}",
        )
        return publish_capture(self.ctx, p, frame)

    def teardown(self) -> None:
        node = getattr(self, "node", None)
        if node is not None:
            node.destroy(self.subscription)
            ros_node.release(node)
