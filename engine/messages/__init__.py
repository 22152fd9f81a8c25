"""Message types: the Python objects stages exchange, and their mapping to protobuf schemas.

Every message carries its source's timestamp ``stamp_ns`` (integer ns), a per-port sequence number
``seq`` (set by the publisher) and the ``frame_id`` its geometry is expressed in. Arrays are numpy;
received arrays may be read-only views of the wire buffer, so stages never modify inputs in place.

Each class names its protobuf ``SCHEMA`` (see engine.messages.schemas); its fields map to the schema's by
name and type, ``WIRE`` naming the rest, and ``to_proto`` / ``from_proto`` are generated from that
(engine.messages.mapping). A class whose payload is one large array names the bytes field that
holds it in ``BULK``: the codec then moves that array without an extra protobuf copy (engine.messages.codec).

Where things are (import them from here, ``engine.messages``):

* ``base`` — :class:`Message` and the hand-over rules of publish (canonical, detach, freeze);
* ``mapping`` — how a message's fields travel in its schema (:class:`Wire`), and the protobuf helpers;
* ``geometry`` — types on Foxglove's schemas (point cloud, image, camera info, pose, transforms,
  joint state, scene meshes), which Foxglove's 3D view shows, and the pose with covariance (a pose
  on vgr's schema that extends Foxglove's);
* ``vgr_v1`` — types on vgr's own schemas (blob, tracker pose, event, calibration result, robot
  command and reply, correction, request).
"""

from __future__ import annotations

from engine.messages.base import WIRE_CACHE, Message, array_fields, canonical, detach, freeze, freeze_arrays
from engine.messages.geometry import (
    CameraInfo,
    FrameTransforms,
    Image,
    JointState,
    Mesh,
    PointCloud,
    PoseStamped,
    PoseWithCovarianceStamped,
    SceneMeshes,
    Transform,
)
from engine.messages.mapping import Bulk, Wire, WireMap, get_pose, get_stamp, set_pose, set_stamp
from engine.messages.vgr_v1 import (
    EVENT_LEVELS,
    ROBOT_COMMAND_KINDS,
    Blob,
    CalibrationResultMsg,
    CellReply,
    Correction,
    Event,
    Request,
    RobotCommand,
    RobotReply,
    TrackerPose,
)

BUILTIN_MESSAGE_TYPES: tuple[type[Message], ...] = (
    PointCloud,
    Image,
    CameraInfo,
    PoseStamped,
    Transform,
    FrameTransforms,
    JointState,
    Blob,
    TrackerPose,
    Event,
    CalibrationResultMsg,
    RobotCommand,
    RobotReply,
    Correction,
    Request,
    CellReply,
    SceneMeshes,
    PoseWithCovarianceStamped,
)

__all__ = [
    "BUILTIN_MESSAGE_TYPES",
    "EVENT_LEVELS",
    "ROBOT_COMMAND_KINDS",
    "WIRE_CACHE",
    "Blob",
    "Bulk",
    "CalibrationResultMsg",
    "CameraInfo",
    "CellReply",
    "Correction",
    "Event",
    "FrameTransforms",
    "Image",
    "JointState",
    "Mesh",
    "Message",
    "PointCloud",
    "PoseStamped",
    "PoseWithCovarianceStamped",
    "Request",
    "RobotCommand",
    "RobotReply",
    "SceneMeshes",
    "TrackerPose",
    "Transform",
    "Wire",
    "WireMap",
    "array_fields",
    "canonical",
    "detach",
    "freeze",
    "freeze_arrays",
    "get_pose",
    "get_stamp",
    "set_pose",
    "set_stamp",
]
