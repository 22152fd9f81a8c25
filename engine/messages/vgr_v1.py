"""Message types on vgr's own versioned schemas (vgr.v1, engine.schemas): blobs, tracker poses,
events, calibration results, robot commands and replies, corrections and service requests."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

import numpy as np

from engine import transforms as tf
from engine.messages.base import Bulk, Message, get_pose, get_stamp, set_pose, set_stamp
from engine.schemas import ProtoMessage


@dataclass(kw_only=True, eq=False)
class Blob(Message):
    """Opaque bytes (transport benchmarks, file contents). Schema vgr.v1.Blob."""

    TYPE: ClassVar[str] = "Blob"
    WIRE_EXACT: ClassVar[bool] = True
    SCHEMA: ClassVar[str] = "vgr.v1.Blob"
    BULK: ClassVar[int | None] = 4

    data: bytes | memoryview = b""
    content_type: str = ""

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.content_type = self.frame_id, self.content_type
        data = self.data
        return pb, data if type(data) is bytes else memoryview(data).cast("B")

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            content_type=pb.content_type,
            data=bulk if bulk is not None else pb.data,
        )


@dataclass(kw_only=True, eq=False)
class TrackerPose(Message):
    """Pose ``T`` = T_frame_tracker of a tracked device (Vive). Schema vgr.v1.TrackerPose."""

    TYPE: ClassVar[str] = "TrackerPose"
    SCHEMA: ClassVar[str] = "vgr.v1.TrackerPose"

    serial: str = ""
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    valid: bool = True
    tracking_result: str = ""

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.serial, pb.valid, pb.tracking_result = (
            self.frame_id,
            self.serial,
            self.valid,
            self.tracking_result,
        )
        set_pose(pb.pose, self.T)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            serial=pb.serial,
            T=get_pose(pb.pose),
            valid=pb.valid,
            tracking_result=pb.tracking_result,
        )


# "result": what a person should read at the end of the run (a verdict, a table); kept in the summary
EVENT_LEVELS = ("debug", "info", "result", "warning", "error", "alarm")


@dataclass(kw_only=True, eq=False)
class Event(Message):
    """Log line, error or alarm. ``code`` is machine-readable; ``details`` is JSON-serialisable."""

    TYPE: ClassVar[str] = "Event"
    SCHEMA: ClassVar[str] = "vgr.v1.Event"

    level: str = "info"
    code: str = ""
    stage: str = ""
    message: str = ""
    traceback: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.level not in EVENT_LEVELS:
            raise ValueError(f"event level {self.level!r} is not one of {EVENT_LEVELS}")

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.level, pb.code, pb.stage, pb.message, pb.traceback = (
            self.level,
            self.code,
            self.stage,
            self.message,
            self.traceback,
        )
        pb.details_json = json.dumps(self.details, sort_keys=True, default=_json_default)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            level=pb.level or "info",
            code=pb.code,
            stage=pb.stage,
            message=pb.message,
            traceback=pb.traceback,
            details=json.loads(pb.details_json) if pb.details_json else {},
        )


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


@dataclass(kw_only=True, eq=False)
class CalibrationResultMsg(Message):
    """A calibration result on the wire: verdict, named transforms, metrics, and the complete
    result as JSON (plugins.solvers.calibration_result.CalibrationResult.to_json())."""

    TYPE: ClassVar[str] = "CalibrationResult"
    SCHEMA: ClassVar[str] = "vgr.v1.CalibrationResult"

    kind: str = ""
    verdict: str = ""
    method: str = ""
    reasons: list[str] = field(default_factory=list)
    transforms: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    result_json: str = ""

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.kind, pb.verdict, pb.method, pb.result_json = (
            self.kind,
            self.verdict,
            self.method,
            self.result_json,
        )
        pb.reasons.extend(self.reasons)
        for name, T in self.transforms.items():
            set_pose(pb.transforms.add(name=name).pose, T)
        for name, v in self.metrics.items():
            pb.metrics.add(name=name, value=float(v))
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            kind=pb.kind,
            verdict=pb.verdict,
            method=pb.method,
            reasons=list(pb.reasons),
            transforms={t.name: get_pose(t.pose) for t in pb.transforms},
            metrics={m.name: m.value for m in pb.metrics},
            result_json=pb.result_json,
        )


ROBOT_COMMAND_KINDS = ("move_j", "move_l", "stop", "state")


@dataclass(kw_only=True, eq=False)
class RobotCommand(Message):
    """A robot command with an id; a controller executes each id at most once."""

    TYPE: ClassVar[str] = "RobotCommand"
    SCHEMA: ClassVar[str] = "vgr.v1.RobotCommand"

    command_id: str = ""
    kind: str = "move_l"
    T: np.ndarray | None = None  # T_base_tcp target
    joints: np.ndarray | None = None  # rad
    speed: float = 0.0
    acceleration: float = 0.0
    comment: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ROBOT_COMMAND_KINDS:
            raise ValueError(f"robot command kind {self.kind!r} is not one of {ROBOT_COMMAND_KINDS}")

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.command_id, pb.kind, pb.comment = (
            self.frame_id,
            self.command_id,
            self.kind,
            self.comment,
        )
        pb.speed, pb.acceleration = self.speed, self.acceleration
        if self.T is not None:
            set_pose(pb.pose, self.T)
        if self.joints is not None:
            pb.joints.extend(np.asarray(self.joints, dtype=float).tolist())
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            command_id=pb.command_id,
            kind=pb.kind,
            T=get_pose(pb.pose) if pb.HasField("pose") else None,
            joints=np.array(pb.joints) if len(pb.joints) else None,
            speed=pb.speed,
            acceleration=pb.acceleration,
            comment=pb.comment,
        )


@dataclass(kw_only=True, eq=False)
class RobotReply(Message):
    """The controller's answer to a RobotCommand: accepted or refused (with the error), final state."""

    TYPE: ClassVar[str] = "RobotReply"
    SCHEMA: ClassVar[str] = "vgr.v1.RobotReply"

    command_id: str = ""
    ok: bool = False
    error: str = ""
    T: np.ndarray | None = None
    joints: np.ndarray | None = None
    duration_s: float = 0.0
    duplicate: bool = False

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.command_id, pb.ok, pb.error = self.frame_id, self.command_id, self.ok, self.error
        pb.duration_s, pb.duplicate = self.duration_s, self.duplicate
        if self.T is not None:
            set_pose(pb.pose, self.T)
        if self.joints is not None:
            pb.joints.extend(np.asarray(self.joints, dtype=float).tolist())
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            command_id=pb.command_id,
            ok=pb.ok,
            error=pb.error,
            T=get_pose(pb.pose) if pb.HasField("pose") else None,
            joints=np.array(pb.joints) if len(pb.joints) else None,
            duration_s=pb.duration_s,
            duplicate=pb.duplicate,
        )


@dataclass(kw_only=True, eq=False)
class Correction(Message):
    """A pose correction (``T``) with its size and the verdict of the safety checks."""

    TYPE: ClassVar[str] = "Correction"
    SCHEMA: ClassVar[str] = "vgr.v1.Correction"

    kind: str = ""
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    verdict: str = "ok"
    reasons: list[str] = field(default_factory=list)

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.kind, pb.verdict = self.frame_id, self.kind, self.verdict
        set_pose(pb.pose, self.T)
        pb.translation_m = float(np.linalg.norm(self.T[:3, 3]))
        pb.rotation_rad = float(np.linalg.norm(tf.log_so3(self.T[:3, :3])))
        pb.reasons.extend(self.reasons)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            kind=pb.kind,
            T=get_pose(pb.pose),
            verdict=pb.verdict,
            reasons=list(pb.reasons),
        )


@dataclass(kw_only=True, eq=False)
class Request(Message):
    """A generic service request: a command word and JSON arguments."""

    TYPE: ClassVar[str] = "Request"
    WIRE_EXACT: ClassVar[bool] = True
    SCHEMA: ClassVar[str] = "vgr.v1.Request"

    command: str = ""
    args: dict[str, Any] = field(default_factory=dict)

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.command = self.command
        pb.args_json = json.dumps(self.args, sort_keys=True, default=_json_default)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(stamp_ns=get_stamp(pb), command=pb.command, args=json.loads(pb.args_json) if pb.args_json else {})
