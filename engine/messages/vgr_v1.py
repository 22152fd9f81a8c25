"""Message types on vgr's own versioned schemas (vgr.v1, engine.messages.schemas): blobs, tracker poses,
events, calibration results, robot commands and replies, corrections and service requests.

Their fields map to the schemas by name and type (engine.messages.mapping); ``WIRE`` names the rest."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from engine import transforms as tf
from engine.messages.base import Message
from engine.messages.mapping import Bulk, Wire, WireMap
from engine.messages.schemas import ProtoMessage


@dataclass(kw_only=True, eq=False)
class Blob(Message, schema="vgr.v1.Blob"):
    """Opaque bytes (transport benchmarks, file contents)."""

    WIRE_EXACT: ClassVar[bool] = True
    BULK: ClassVar[int | None] = 4

    data: bytes | memoryview = b""
    content_type: str = ""


@dataclass(kw_only=True, eq=False)
class TrackerPose(Message, schema="vgr.v1.TrackerPose"):
    """Pose ``T`` = T_frame_tracker of a tracked device (Vive)."""

    WIRE: ClassVar[WireMap] = {"T": "pose"}

    serial: str = ""
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    valid: bool = True
    tracking_result: str = ""


# "result": what a person should read at the end of the run (a verdict, a table); kept in the summary
EVENT_LEVELS = ("debug", "info", "result", "warning", "error", "alarm")


@dataclass(kw_only=True, eq=False)
class Event(Message, schema="vgr.v1.Event"):
    """Log line, error or alarm. ``code`` is machine-readable; ``details`` is JSON-serialisable."""

    WIRE: ClassVar[WireMap] = {"level": Wire(unset_is_default=True), "details": "details_json"}

    level: str = "info"
    code: str = ""
    stage: str = ""
    message: str = ""
    traceback: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.level not in EVENT_LEVELS:
            raise ValueError(f"event level {self.level!r} is not one of {EVENT_LEVELS}")


@dataclass(kw_only=True, eq=False)
class CalibrationResultMsg(Message, schema="vgr.v1.CalibrationResult"):
    """A calibration result on the wire: verdict, named transforms, metrics, and the complete
    result as JSON (plugins.calibration.result.CalibrationResult.to_json())."""

    TYPE: ClassVar[str] = "CalibrationResult"

    kind: str = ""
    verdict: str = ""
    method: str = ""
    reasons: list[str] = field(default_factory=list)
    transforms: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    result_json: str = ""


ROBOT_COMMAND_KINDS = ("move_j", "move_l", "stop", "state")


@dataclass(kw_only=True, eq=False)
class RobotCommand(Message, schema="vgr.v1.RobotCommand"):
    """A robot command with an id; a controller executes each id at most once."""

    WIRE: ClassVar[WireMap] = {"T": "pose"}

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


@dataclass(kw_only=True, eq=False)
class RobotReply(Message, schema="vgr.v1.RobotReply"):
    """The controller's answer to a RobotCommand: accepted or refused (with the error), final state."""

    WIRE: ClassVar[WireMap] = {"T": "pose"}

    command_id: str = ""
    ok: bool = False
    error: str = ""
    T: np.ndarray | None = None
    joints: np.ndarray | None = None
    duration_s: float = 0.0
    duplicate: bool = False


@dataclass(kw_only=True, eq=False)
class Correction(Message, schema="vgr.v1.Correction"):
    """A pose correction (``T``) with its size and the verdict of the safety checks."""

    WIRE: ClassVar[WireMap] = {"T": "pose"}

    kind: str = ""
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    verdict: str = "ok"
    reasons: list[str] = field(default_factory=list)

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb, bulk = super().to_proto()  # and the size of T, for readers of the wire (not read back)
        pb.translation_m = float(np.linalg.norm(self.T[:3, 3]))
        pb.rotation_rad = float(np.linalg.norm(tf.log_so3(self.T[:3, :3])))
        return pb, bulk


@dataclass(kw_only=True, eq=False)
class Request(Message, schema="vgr.v1.Request"):
    """A generic service request: a command word and JSON arguments."""

    WIRE_EXACT: ClassVar[bool] = True
    WIRE: ClassVar[WireMap] = {"args": "args_json"}

    command: str = ""
    args: dict[str, Any] = field(default_factory=dict)


@dataclass(kw_only=True, eq=False)
class CellReply(Message, schema="vgr.v1.CellReply"):
    """A cell service job's answer to its :class:`Request`: a status of engine.run.cell.codes, a
    message for people and the command's result (plain JSON data)."""

    WIRE_EXACT: ClassVar[bool] = True
    WIRE: ClassVar[WireMap] = {"result": "result_json"}

    status: str = "fault"
    message: str = ""
    result: dict[str, Any] = field(default_factory=dict)
