"""What every ROS 2 <-> vgr conversion shares: the error, the typestore, time stamps and frame names.

* :class:`ConversionError`: a ROS message (or a vgr message) that cannot be converted; its text
  names the topic and the field (``/camera/points: sensor_msgs/msg/PointCloud2.point_step: ...``).
* :func:`typestore`: the ``rosbags`` typestore of ROS 2 **Jazzy** (imported lazily: ``rosbags``
  is the optional extra ``vgr[ros2]``). Jazzy because it is the current LTS, its rosbag2 metadata
  (version 9, with type hashes) is what ``rosbags``' writer produces, and the message definitions
  vgr converts (std_msgs, builtin_interfaces, sensor_msgs, geometry_msgs, tf2_msgs) are the same,
  field for field, in Humble, Jazzy and Kilted (the rclpy wheels this project tests with): a test
  checks that, so CDR from any of them decodes here.
* Time: ``builtin_interfaces/Time`` (``sec`` int32, ``nanosec`` uint32 in [0, 1e9)) <-> vgr's
  integer nanoseconds, exact both ways (``sec = floor(ns / 1e9)``, as ROS' ``rclcpp::Time`` does
  for times before the epoch too).
* Frames: :class:`FrameMap`, ROS frame id -> vgr frame name and back. A plain mapping (or None)
  maps the frames it names and passes the others through unchanged; ``FrameMap(m, strict=True)``
  refuses a frame it does not name (ConversionError naming the field). The empty frame id is
  always passed through.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

STORE_NAME = "ros2_jazzy"
EXTRA_HINT = "pip install vgr[ros2]"
NS_PER_S = 1_000_000_000
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


class ConversionError(ValueError):
    """A message that cannot be converted; ``topic`` and ``field`` say where."""

    def __init__(self, topic: str | None, field: str | None = None, problem: str | None = None) -> None:
        if field is None:  # ConversionError("a whole sentence"): the caller named topic and field itself
            self.topic, self.field, self.problem = "", "", topic or ""
            super().__init__(self.problem)
            return
        self.topic = topic or ""
        self.field = field
        self.problem = problem or ""
        super().__init__(f"{self.topic or '(no topic)'}: {field}: {self.problem}")


class NothingConvertedError(Exception):
    """Nothing of a bag or recording converts, so nothing is written (exit code 1); ``skipped`` says
    which topics were passed over and why."""

    def __init__(self, message: str, skipped: list[dict[str, str]]) -> None:
        super().__init__(message)
        self.skipped = skipped


class MissingExtraError(ImportError):
    """``rosbags`` (the ``vgr[ros2]`` extra) is not installed."""


@functools.cache
def typestore() -> Any:
    """The ``rosbags`` typestore of ROS 2 Jazzy (MissingExtraError without the ``ros2`` extra)."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:
        raise MissingExtraError(f"vgr's ROS 2 support needs the rosbags library ({exc}): {EXTRA_HINT}") from None
    return get_typestore(Stores(STORE_NAME))


def ros_class(msgtype: str) -> Any:
    """The typestore dataclass of ROS type *msgtype* (``sensor_msgs/msg/PointCloud2``)."""
    return typestore().types[msgtype]


# --------------------------------------------------------------------------- time


def stamp_ns(stamp: Any) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/Time``."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def ros_time(ns: int, *, topic: str | None, field: str = "header.stamp") -> Any:
    """The ``builtin_interfaces/Time`` of *ns* (ConversionError when its seconds do not fit int32)."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    if not INT32_MIN <= sec <= INT32_MAX:
        raise ConversionError(topic, field, f"{ns} ns is outside ROS time's int32 seconds")
    return ros_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


# --------------------------------------------------------------------------- frames


class FrameMap(Mapping[str, str]):
    """ROS frame id -> vgr frame name (and back); *strict*: a frame not named is an error."""

    def __init__(self, mapping: Mapping[str, str] | None = None, *, strict: bool = False) -> None:
        self._to_vgr: dict[str, str] = dict(mapping or {})
        self._to_ros: dict[str, str] = {}
        for ros, vgr in self._to_vgr.items():
            self._to_ros.setdefault(vgr, ros)  # several ROS frames for one vgr frame: the first goes back
        self.strict = strict

    def __getitem__(self, key: str) -> str:
        return self._to_vgr[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._to_vgr)

    def __len__(self) -> int:
        return len(self._to_vgr)

    def to_vgr(self, frame: str, *, topic: str | None, field: str) -> str:
        if not frame:
            return frame
        got = self._to_vgr.get(frame)
        if got is not None:
            return got
        if self.strict:
            raise ConversionError(topic, field, f"frame {frame!r} is not in the frame mapping ({self._known()})")
        return frame

    def to_ros(self, frame: str, *, topic: str | None, field: str) -> str:
        if not frame:
            return frame
        got = self._to_ros.get(frame)
        if got is not None:
            return got
        if self.strict:
            raise ConversionError(topic, field, f"vgr frame {frame!r} is not in the frame mapping ({self._known()})")
        return frame

    def _known(self) -> str:
        return ", ".join(f"{r} -> {v}" for r, v in self._to_vgr.items()) or "empty"


def frame_map(frames: Mapping[str, str] | None) -> FrameMap:
    """*frames* as a :class:`FrameMap` (a plain mapping or None: not strict)."""
    return frames if isinstance(frames, FrameMap) else FrameMap(frames)


@dataclass
class Ctx:
    """Where a conversion is: the topic and ROS type (for errors), the frames, and notes on what
    was dropped (read by ``vgr bag`` for its summary)."""

    topic: str | None
    msgtype: str
    frames: FrameMap
    notes: list[str] = field(default_factory=list)

    def error(self, field: str, problem: str) -> ConversionError:
        return ConversionError(self.topic, f"{self.msgtype}.{field}", problem)

    def to_vgr(self, frame: str, field: str = "header.frame_id") -> str:
        return self.frames.to_vgr(frame, topic=self.topic, field=f"{self.msgtype}.{field}")

    def to_ros(self, frame: str, field: str = "header.frame_id") -> str:
        return self.frames.to_ros(frame, topic=self.topic, field=f"{self.msgtype}.{field}")

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    def header(self, ns: int, frame: str) -> Any:
        """A ``std_msgs/Header`` of vgr stamp *ns* and vgr frame *frame*."""
        return ros_class("std_msgs/msg/Header")(
            stamp=ros_time(ns, topic=self.topic, field=f"{self.msgtype}.header.stamp"), frame_id=self.to_ros(frame)
        )
