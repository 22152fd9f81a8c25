"""The cell service's ROS 2 gateway: ``locate`` / ``guide`` / ``status`` from a ROS 2 node with
standard message types only, and each correction published as a pose and on ``/tf``.

Started by a served recipe's ``serve.gateways: {ros2: {...}}`` (docs/cell_service.md, docs/ros2.md)::

    gateways:
      ros2:
        ros: {domain_id: 0, discovery: localhost}
        namespace: /vgr                  # the gateway's names below live in it
        joint_states: /joint_states      # the robot's joints for a Trigger request
        joint_names: [shoulder_pan_joint, ...]   # their order for the locator's robot_model (unset: as sent)
        base_frame: base_link            # the ROS frame of the robot's base (TF parent of the correction)
        tf_child_frame: vgr_correction   # the TF child frame of the correction

What a ROS 2 node sees (names inside ``namespace``):

``locate``, ``status`` (``std_srvs/srv/Trigger``)
    ``ros2 service call /vgr/locate std_srvs/srv/Trigger``: a locate of one part with the robot's
    latest ``joint_states`` as ``joints_rad`` (the locator's recipe names its ``robot_model``);
    ``success`` is true when the reply's status is ``ok``, ``message`` the whole reply document
    (JSON, engine/run/cell/schemas/cell_api.schema.json).
``request`` -> ``reply`` (``std_msgs/msg/String``, JSON)
    Any request document of the cell API with its ``command`` added (``{"command": "guide", "id":
    ..., "step": 0, "pose": ...}``) gets its reply document on ``reply`` (reliable, depth 10).
``correction`` (``geometry_msgs/msg/PoseStamped``) and ``/tf``
    After every ``ok`` locate (the first part) and every converged guide, the correction ``C``
    (apply as corrected = C · taught, in ``base_frame``) is published as a pose in ``base_frame``
    and as the transform ``base_frame -> tf_child_frame`` (``tf2_msgs/msg/TFMessage``: when the
    ``tf2_msgs`` package is absent the pose topic still carries it and a warning says so).

The service callbacks block while the cycle runs, so the gateway has a ROS 2 node and executor of
its own (:class:`plugins.ros2.node.RosNode`): it never holds up a bridge stage's subscriptions.
Requests are answered one at a time; the cell service answers ``busy`` to a job while one runs.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from engine.messages import FrameTransforms, JointState, PoseStamped, Transform
from engine.run.cell.protocol import pose_from_doc
from plugins.ros2 import node as ros_node
from plugins.ros2.inbox import Inbox
from plugins.ros2.qos import profile
from plugins.ros2.ros_types import ros_class
from plugins.util.sdk import MissingSDKError

Handler = Callable[[str, dict[str, Any]], dict[str, Any]]
JOINT_STATE = "sensor_msgs/msg/JointState"
POSE = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"


class Ros2GatewaySettings(BaseModel):
    """The ``ros2`` gateway settings of a cell service."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ros: ros_node.RosSettings = Field(default_factory=ros_node.RosSettings)
    namespace: str = Field("/vgr", pattern=r"^(/[A-Za-z][A-Za-z0-9_]*)+$|^$")
    joint_states: str = "/joint_states"
    joint_names: list[str] | None = None
    base_frame: str = Field("base_link", min_length=1)
    tf_child_frame: str = Field("vgr_correction", min_length=1)


class Ros2Gateway:
    """The gateway's node, services, topics and its request counter."""

    def __init__(self, handle: Handler, settings: Ros2GatewaySettings, log: logging.Logger | None) -> None:
        self.handle, self.settings = handle, settings
        self.log = log or logging.getLogger("vgr.ros2.gateway")
        rclpy = ros_node.rclpy_module("ros2 gateway")
        if settings.ros.discovery is not None:
            import os

            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = settings.ros.discovery.upper()
        self.ros = ros_node.RosNode(rclpy, ros_node.domain_of(settings.ros), settings.ros.namespace)
        self._lock = threading.Lock()
        self._count = 0
        self.joints = Inbox(settings.joint_states)
        node, ns = self.ros.node, settings.namespace
        self._subs = [
            self.ros.subscribe_raw(ros_class(JOINT_STATE), settings.joint_states, profile("reliable"), self.joints.put),
            node.create_subscription(ros_class("std_msgs/msg/String"), f"{ns}/request", self._on_request, 10),
        ]
        trigger = ros_class("std_srvs/srv/Trigger")
        self._services = [
            node.create_service(trigger, f"{ns}/locate", self._on_locate),
            node.create_service(trigger, f"{ns}/status", self._on_status),
        ]
        self.reply_pub = node.create_publisher(ros_class("std_msgs/msg/String"), f"{ns}/reply", 10)
        self.pose_pub = node.create_publisher(ros_class(POSE), f"{ns}/correction", 10)
        try:
            self.tf_pub: Any = node.create_publisher(ros_class(TF), "/tf", 100)
        except MissingSDKError as exc:
            self.tf_pub = None
            self.log.warning("the correction is not published on /tf: %s", exc)
        self.address = f"ROS 2 domain {self.ros.domain_id}, {ns}/locate, {ns}/status, {ns}/request"

    # -- requests --------------------------------------------------------------------------------
    def _next_id(self, prefix: str) -> str:
        with self._lock:
            self._count += 1
            return f"ros2-{prefix}-{self._count}"

    def _joints_rad(self) -> list[float]:
        from plugins.ros2.convert import decode

        latest = self.joints.latest()
        if latest is None:
            raise ValueError(f"no message on {self.settings.joint_states!r} yet: the robot's joints are not known")
        js = decode(JOINT_STATE, latest.data, topic=self.settings.joint_states)
        assert isinstance(js, JointState)
        order = self.settings.joint_names
        if order is None:
            return [float(v) for v in js.positions]
        missing = [n for n in order if n not in js.names]
        if missing:
            raise ValueError(f"{self.settings.joint_states!r}: name has no {missing} (joint_names of the gateway)")
        return [float(js.positions[js.names.index(n)]) for n in order]

    def run(self, command: str, doc: dict[str, Any]) -> dict[str, Any]:
        """The reply document of one request, the correction published when there is one."""
        reply = self.handle(command, doc)
        with contextlib.suppress(Exception):  # publishing is a courtesy: the reply is the answer
            self._publish_correction(reply)
        return reply

    def _on_locate(self, request: Any, response: Any) -> Any:
        try:
            doc: dict[str, Any] = {"id": self._next_id("locate"), "joints_rad": self._joints_rad()}
        except Exception as exc:
            response.success, response.message = False, json.dumps({"status": "invalid_request", "message": str(exc)})
            return response
        reply = self.run("locate", doc)
        response.success = reply.get("status") == "ok"
        response.message = json.dumps(reply, allow_nan=False)
        return response

    def _on_status(self, request: Any, response: Any) -> Any:
        reply = self.handle("status", {})
        response.success = reply.get("status") == "ok"
        response.message = json.dumps(reply, allow_nan=False)
        return response

    def _on_request(self, msg: Any) -> None:
        try:
            doc = json.loads(msg.data)
            if not isinstance(doc, dict) or not isinstance(doc.get("command"), str):
                raise ValueError("a request is a JSON object with a 'command'")
            command = doc.pop("command")
            reply = self.run(command, doc)
        except Exception as exc:  # answered, never raised into the executor
            reply = {"status": "invalid_request", "message": f"request on {self.settings.namespace}/request: {exc}"}
        out = ros_class("std_msgs/msg/String")()
        out.data = json.dumps(reply, allow_nan=False)
        self.reply_pub.publish(out)

    # -- the correction out ----------------------------------------------------------------------
    def _publish_correction(self, reply: dict[str, Any]) -> None:
        from plugins.ros2.convert import encode

        result = reply.get("result") or {}
        doc = result.get("correction") if reply.get("command") == "guide" else None
        if reply.get("command") == "locate" and result.get("parts"):
            doc = result["parts"][0].get("correction")
        if reply.get("status") != "ok" or not doc:
            return
        T = pose_from_doc(doc, "correction")
        stamp = self.ros.node.get_clock().now().nanoseconds
        s = self.settings
        self.pose_pub.publish(encode(PoseStamped(T=T, frame_id=s.base_frame, stamp_ns=stamp), POSE))
        if self.tf_pub is not None:
            edge = Transform(frame_id=s.base_frame, child_frame_id=s.tf_child_frame, T=np.asarray(T), stamp_ns=stamp)
            self.tf_pub.publish(encode(FrameTransforms(stamp_ns=stamp, transforms=[edge]), TF))

    def close(self) -> None:
        self.ros.close()


def start_gateway(handle: Handler, settings: dict[str, Any], log: logging.Logger | None = None) -> Ros2Gateway:
    """A started ROS 2 gateway from its settings mapping (ValueError with readable text)."""
    try:
        parsed = Ros2GatewaySettings.model_validate(settings)
    except ValidationError as exc:
        lines = [f"{'.'.join(str(p) for p in e['loc']) or 'ros2'}: {e['msg']}" for e in exc.errors()]
        raise ValueError("ros2 gateway settings: " + "; ".join(lines)) from None
    return Ros2Gateway(handle, parsed, log)
