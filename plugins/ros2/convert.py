"""ROS 2 standard messages <-> vgr messages: the one place where they are converted (bridge and bags).

The public API (docs/ros2.md has the table of what maps to what and what is dropped):

* :func:`decode` ``(msgtype, cdr, *, topic, frames=None) -> Message``: CDR bytes as rclpy's raw
  subscription delivers them (with the 4-byte encapsulation header) -> a vgr message;
* :func:`encode` ``(message, msgtype, *, frames=None) -> bytes``: a vgr message -> CDR bytes that
  rclpy publishes as a serialized message;
* :func:`from_ros` / :func:`to_ros`: the same on the ``rosbags`` typestore's dataclasses (the bags
  use them); ``notes=`` collects what a conversion dropped (fields, invalid points);
* :data:`SUPPORTED` (ROS type -> vgr type), :data:`ROS_TYPES` (vgr type -> its ROS type),
  :func:`ros_type_of`;
* :class:`ConversionError` (a ValueError naming the topic and the field), :class:`FrameMap`
  (frame ids mapped ROS -> vgr and back, optionally strict), :class:`MissingExtraError`.

CDR and the message classes come from the ``rosbags`` library (typestore of ROS 2 Jazzy, see
plugins.ros2.convert_common), imported on first use: without the ``vgr[ros2]`` extra the module
imports and :data:`SUPPORTED` is there, and a conversion raises MissingExtraError saying
``pip install vgr[ros2]``. Time stamps are exact both ways (``sec``/``nanosec`` <-> integer ns).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from engine.messages import (
    CameraInfo,
    FrameTransforms,
    Image,
    JointState,
    Message,
    PointCloud,
    PoseStamped,
    PoseWithCovarianceStamped,
    Transform,
)
from plugins.ros2.convert_common import (
    ConversionError,
    Ctx,
    FrameMap,
    MissingExtraError,
    frame_map,
    typestore,
)

__all__ = [
    "ROS_TYPES",
    "SUPPORTED",
    "ConversionError",
    "FrameMap",
    "MissingExtraError",
    "decode",
    "encode",
    "from_ros",
    "ros_type_of",
    "to_ros",
]

#: ROS 2 type -> the vgr type it converts to and from
SUPPORTED: dict[str, type[Message]] = {
    "sensor_msgs/msg/PointCloud2": PointCloud,
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/CameraInfo": CameraInfo,
    "sensor_msgs/msg/JointState": JointState,
    "geometry_msgs/msg/PoseStamped": PoseStamped,
    "geometry_msgs/msg/PoseWithCovarianceStamped": PoseWithCovarianceStamped,
    "geometry_msgs/msg/TransformStamped": Transform,
    "tf2_msgs/msg/TFMessage": FrameTransforms,
}

#: vgr type -> the ROS 2 type it is sent as (``vgr bag export``, a bridge output without a type)
ROS_TYPES: dict[type[Message], str] = {cls: ros for ros, cls in SUPPORTED.items()}


def ros_type_of(cls: type[Message]) -> str | None:
    """The ROS 2 type vgr type *cls* is sent as (its own, else its nearest base's); None: none."""
    for base in cls.__mro__:
        if base in ROS_TYPES:
            return ROS_TYPES[base]  # type: ignore[index]
    return None


def _converters() -> dict[str, tuple[Callable[[Any, Ctx], Message], Callable[[Any, Ctx], Any]]]:
    from plugins.ros2 import convert_cloud as cc
    from plugins.ros2 import convert_geometry as cg
    from plugins.ros2 import convert_image as ci

    return {
        "sensor_msgs/msg/PointCloud2": (cc.cloud_from_ros, cc.cloud_to_ros),
        "sensor_msgs/msg/Image": (ci.image_from_ros, ci.image_to_ros),
        "sensor_msgs/msg/CameraInfo": (ci.camera_info_from_ros, ci.camera_info_to_ros),
        "sensor_msgs/msg/JointState": (cg.joints_from_ros, cg.joints_to_ros),
        "geometry_msgs/msg/PoseStamped": (cg.pose_from_ros, cg.pose_to_ros),
        "geometry_msgs/msg/PoseWithCovarianceStamped": (cg.pose_cov_from_ros, cg.pose_cov_to_ros),
        "geometry_msgs/msg/TransformStamped": (cg.transform_from_ros, cg.transform_to_ros),
        "tf2_msgs/msg/TFMessage": (cg.tf_from_ros, cg.tf_to_ros),
    }


_CONVERTERS: dict[str, tuple[Callable[[Any, Ctx], Message], Callable[[Any, Ctx], Any]]] = {}


def _converter(msgtype: str, topic: str | None) -> tuple[Callable[[Any, Ctx], Message], Callable[[Any, Ctx], Any]]:
    if not _CONVERTERS:
        _CONVERTERS.update(_converters())
    conv = _CONVERTERS.get(msgtype)
    if conv is None:
        raise ConversionError(
            topic, "type", f"{msgtype} has no vgr conversion; vgr converts {', '.join(sorted(SUPPORTED))}"
        )
    return conv


def from_ros(
    msgtype: str,
    ros_msg: Any,
    *,
    topic: str | None,
    frames: Mapping[str, str] | None = None,
    notes: list[str] | None = None,
) -> Message:
    """The vgr message of *ros_msg* (a typestore dataclass of ROS type *msgtype*); what was
    dropped is appended to *notes* (when given)."""
    conv = _converter(msgtype, topic)
    cx = Ctx(topic, msgtype, frame_map(frames))
    try:
        msg = conv[0](ros_msg, cx)
    except ConversionError:
        raise
    except (ValueError, TypeError, AttributeError) as exc:  # a vgr type refusing a value, a field missing
        raise ConversionError(topic, msgtype, f"{type(exc).__name__}: {exc}") from None
    if notes is not None:
        notes.extend(n for n in cx.notes if n not in notes)
    return msg


def to_ros(message: Message, msgtype: str, *, frames: Mapping[str, str] | None = None, topic: str | None = None) -> Any:
    """The typestore dataclass (ROS type *msgtype*) of vgr *message*."""
    conv = _converter(msgtype, topic)
    want = SUPPORTED[msgtype]
    if not isinstance(message, want):
        raise ConversionError(topic, "type", f"{msgtype} is sent from a vgr {want.TYPE}, not a {message.TYPE}")
    cx = Ctx(topic, msgtype, frame_map(frames))
    try:
        return conv[1](message, cx)
    except ConversionError:
        raise
    except (ValueError, TypeError) as exc:
        raise ConversionError(topic, msgtype, f"{type(exc).__name__}: {exc}") from None


def decode(
    msgtype: str,
    cdr: bytes | memoryview,
    *,
    topic: str,
    frames: Mapping[str, str] | None = None,
    notes: list[str] | None = None,
) -> Message:
    """The vgr message of serialized CDR *cdr* (encapsulation header first) of ROS type *msgtype*."""
    _converter(msgtype, topic)  # (an unconvertible type is said before anything is parsed)
    store = typestore()
    try:
        # a memoryview: rosbags slices off the encapsulation header, and a slice of bytes would copy them all
        ros_msg = store.deserialize_cdr(memoryview(cdr), msgtype)
    except Exception as exc:  # rosbags raises struct.error, IndexError, ValueError ... on bad bytes
        raise ConversionError(
            topic, f"{msgtype} (CDR)", f"{len(cdr)} bytes do not deserialize: {type(exc).__name__}: {exc}"
        ) from None
    return from_ros(msgtype, ros_msg, topic=topic, frames=frames, notes=notes)


def encode(
    message: Message, msgtype: str, *, frames: Mapping[str, str] | None = None, topic: str | None = None
) -> bytes:
    """CDR bytes (little-endian, encapsulation header first) of vgr *message* as ROS type *msgtype*."""
    ros_msg = to_ros(message, msgtype, frames=frames, topic=topic)
    return bytes(typestore().serialize_cdr(ros_msg, msgtype))
