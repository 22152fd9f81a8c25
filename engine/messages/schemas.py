"""Protobuf schemas of every message on the wire and in recordings.

Geometry travels as the well-known Foxglove schemas (``foxglove.PointCloud``, ``foxglove.RawImage``,
``foxglove.PoseInFrame``, ``foxglove.FrameTransform(s)``, ``foxglove.JointStates``,
``foxglove.CameraCalibration``, ``foxglove.SceneUpdate``) so a recording opens in Foxglove with a 3D
view. Everything else uses vgr's own schemas in the versioned package ``vgr.v1``, written below in
proto3 syntax. A new incompatible revision goes to ``vgr.v2``; fields are only ever added.

The vgr schemas are built at import time from their proto text into the default descriptor pool
(no protoc step, no generated files): :func:`define_proto` accepts the subset of proto3 used here
(top-level messages with scalar, message and ``repeated`` fields). Third-party plugins may call it
for their own message types. ``vgr schemas`` prints every schema.
"""

from __future__ import annotations

import re
from typing import Any

from foxglove_schemas_protobuf import (  # noqa: F401  (imports register the files in the pool)
    CameraCalibration_pb2,
    FrameTransform_pb2,
    FrameTransforms_pb2,
    JointStates_pb2,
    PointCloud_pb2,
    Pose_pb2,
    PoseInFrame_pb2,
    RawImage_pb2,
    SceneUpdate_pb2,
)
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2  # noqa: F401
from google.protobuf.message import Message as ProtoMessage

__all__ = ["SCHEMA_VERSION", "ProtoMessage", "define_proto", "descriptor_set", "proto_class", "proto_text"]

SCHEMA_VERSION = 1

_SCALARS = {
    "double": descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
    "float": descriptor_pb2.FieldDescriptorProto.TYPE_FLOAT,
    "int64": descriptor_pb2.FieldDescriptorProto.TYPE_INT64,
    "uint64": descriptor_pb2.FieldDescriptorProto.TYPE_UINT64,
    "int32": descriptor_pb2.FieldDescriptorProto.TYPE_INT32,
    "uint32": descriptor_pb2.FieldDescriptorProto.TYPE_UINT32,
    "bool": descriptor_pb2.FieldDescriptorProto.TYPE_BOOL,
    "string": descriptor_pb2.FieldDescriptorProto.TYPE_STRING,
    "bytes": descriptor_pb2.FieldDescriptorProto.TYPE_BYTES,
}
_FIELD = re.compile(r"^(repeated\s+)?([\w.]+)\s+(\w+)\s*=\s*(\d+)\s*;$")
_MESSAGE = re.compile(r"message\s+(\w+)\s*\{(.*?)\}", re.S)
_TEXTS: dict[str, str] = {}


def _import_for(type_name: str) -> str:
    if type_name == "google.protobuf.Timestamp":
        return "google/protobuf/timestamp.proto"
    if type_name.startswith("foxglove."):
        return f"foxglove/{type_name.split('.', 1)[1]}.proto"
    raise ValueError(f"cannot infer the import for message type {type_name!r}")


def define_proto(file_name: str, package: str, text: str) -> dict[str, type[ProtoMessage]]:
    """Register the messages of a proto3 *text* under *file_name* and return their classes by name.

    Idempotent: defining the same file twice returns the existing classes.
    """
    pool = descriptor_pool.Default()
    fdp = descriptor_pb2.FileDescriptorProto(name=file_name, package=package, syntax="proto3")
    local = {m.group(1) for m in _MESSAGE.finditer(text)}
    deps: set[str] = set()
    for m in _MESSAGE.finditer(text):
        msg = fdp.message_type.add(name=m.group(1))
        for raw in m.group(2).strip().splitlines():
            line = raw.split("//")[0].strip()
            if not line:
                continue
            fm = _FIELD.match(line)
            if fm is None:
                raise ValueError(f"{file_name}: cannot parse field line {line!r}")
            repeated, ftype, fname, number = fm.groups()
            f = msg.field.add(name=fname, number=int(number), json_name=fname)
            f.label = (
                descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED
                if repeated
                else descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL
            )
            if ftype in _SCALARS:
                f.type = _SCALARS[ftype]
            else:
                f.type = descriptor_pb2.FieldDescriptorProto.TYPE_MESSAGE
                if ftype in local:
                    f.type_name = f".{package}.{ftype}"
                else:
                    f.type_name = f".{ftype}"
                    deps.add(_import_for(ftype))
    fdp.dependency.extend(sorted(deps))
    try:
        pool.FindFileByName(file_name)
    except KeyError:
        pool.Add(fdp)
    for name in local:
        _TEXTS[f"{package}.{name}"] = _message_text(text, name)
    return {name: proto_class(f"{package}.{name}") for name in local}


def _message_text(text: str, name: str) -> str:
    for m in _MESSAGE.finditer(text):
        if m.group(1) == name:
            return m.group(0)
    return ""


def proto_class(full_name: str) -> type[ProtoMessage]:
    """The generated message class of a fully qualified protobuf type (e.g. ``foxglove.PointCloud``)."""
    desc = descriptor_pool.Default().FindMessageTypeByName(full_name)
    return message_factory.GetMessageClass(desc)


def descriptor_set(full_name: str) -> bytes:
    """The serialised ``google.protobuf.FileDescriptorSet`` of *full_name* and every file it imports:
    the schema record vgr writes in MCAP and publishes on the bus (docs/zenoh_layout.md), from
    which any protobuf library builds the message class."""
    data = _DESCRIPTOR_SETS.get(full_name)
    if data is None:
        from mcap_protobuf.schema import build_file_descriptor_set

        data = _DESCRIPTOR_SETS[full_name] = build_file_descriptor_set(proto_class(full_name)).SerializeToString()
    return data


_DESCRIPTOR_SETS: dict[str, bytes] = {}


def proto_text(full_name: str) -> str:
    """Human-readable proto3 text of a message type (vgr schemas verbatim, others from descriptors)."""
    if _TEXTS.get(full_name):
        return _TEXTS[full_name]
    desc = descriptor_pool.Default().FindMessageTypeByName(full_name)
    lines = [f"message {desc.name} {{  // {desc.file.name}"]
    for f in desc.fields:
        tname = (
            f.message_type.full_name
            if f.message_type
            else (f.enum_type.full_name if f.enum_type else _scalar_name(f.type))
        )
        rep = "repeated " if _is_repeated(f) else ""
        lines.append(f"  {rep}{tname} {f.name} = {f.number};")
    lines.append("}")
    return "\n".join(lines)


def _is_repeated(f: Any) -> bool:
    rep = getattr(f, "is_repeated", None)
    if rep is not None:
        return bool(rep)
    return bool(f.label == f.LABEL_REPEATED)


def _scalar_name(t: int) -> str:
    names = {v: k.removeprefix("TYPE_").lower() for k, v in descriptor_pb2.FieldDescriptorProto.Type.items()}
    return names.get(t, str(t))


# --------------------------------------------------------------------------- vgr.v1

VGR_V1 = define_proto(
    "vgr/v1/messages.proto",
    "vgr.v1",
    """
message Blob {                       // opaque bytes (transport tests, file contents)
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;
  string content_type = 3;
  bytes data = 4;
}
message TrackerPose {                // one tracked device (Vive tracker) in the base-station frame
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;               // base-station (lighthouse) frame
  string serial = 3;
  foxglove.Pose pose = 4;            // T_frame_tracker
  bool valid = 5;
  string tracking_result = 6;        // e.g. Running_OK, Running_OutOfRange
}
message Event {                      // log line, error or alarm raised by a stage
  google.protobuf.Timestamp timestamp = 1;
  string level = 2;                  // debug | info | warning | error | alarm
  string code = 3;                   // machine-readable, e.g. stage_exception, correction_limit
  string stage = 4;
  string message = 5;
  string traceback = 6;
  string details_json = 7;
}
message NamedTransform {
  string name = 1;                   // e.g. T_tcp_cam
  foxglove.Pose pose = 2;
}
message Metric {
  string name = 1;                   // with its unit suffix, e.g. rms_mm
  double value = 2;
}
message CalibrationResult {          // plugins/calibration/result.py, complete in result_json
  google.protobuf.Timestamp timestamp = 1;
  string kind = 2;
  string verdict = 3;                // ok | warning | degenerate | failed
  string method = 4;
  repeated string reasons = 5;
  repeated NamedTransform transforms = 6;
  repeated Metric metrics = 7;
  string result_json = 8;
}
message RobotCommand {               // a move the robot executes at most once (command_id)
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;               // frame of pose, normally the robot base
  string command_id = 3;
  string kind = 4;                   // move_j | move_l | stop | state
  foxglove.Pose pose = 5;            // T_base_tcp target (move_l, or move_j by IK)
  repeated double joints = 6;        // rad (move_j)
  double speed = 7;                  // m/s (move_l) or rad/s (move_j); 0 = default
  double acceleration = 8;           // m/s^2 or rad/s^2; 0 = default
  string comment = 9;
}
message RobotReply {
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;
  string command_id = 3;
  bool ok = 4;
  string error = 5;
  foxglove.Pose pose = 6;            // T_base_tcp after the command
  repeated double joints = 7;        // rad after the command
  double duration_s = 8;
  bool duplicate = 9;                // true when command_id had been executed before
}
message Correction {                 // a pose correction computed by an action stage
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;
  string kind = 3;                   // delta_tool | delta_base | install_corrected | ...
  foxglove.Pose pose = 4;
  double translation_m = 5;
  double rotation_rad = 6;
  string verdict = 7;                // ok | refused
  repeated string reasons = 8;
}
message Request {                    // a generic service request (capture now, get state, ...)
  google.protobuf.Timestamp timestamp = 1;
  string command = 2;
  string args_json = 3;
}
message CellReply {                  // a cell service job's answer (engine.run.cell)
  google.protobuf.Timestamp timestamp = 1;
  string status = 2;                 // a name of engine.run.cell.codes: ok | no_part | ...
  string message = 3;                // for people: what happened, what to do
  string result_json = 4;            // the command's result (its schema is the command's)
}
""",
)


# --------------------------------------------------------------------------- vgr.v1 pose with covariance
# A file of its own: adding a message to vgr/v1/messages.proto would change the schema records (the
# file descriptor set) that recordings store for every type of that file.

VGR_V1_POSE_COVARIANCE = define_proto(
    "vgr/v1/pose_with_covariance.proto",
    "vgr.v1",
    """
message PoseWithCovarianceInFrame {  // foxglove.PoseInFrame's fields + ROS PoseWithCovariance's covariance
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;
  foxglove.Pose pose = 3;            // T_frame_entity
  repeated double covariance = 4;    // 6x6 row-major, (x, y, z, rot x, rot y, rot z): m, rad, in frame_id
}
""",
)


# --------------------------------------------------------------------------- vgr.v1 recording records
# Written by engine.recording.recorder next to the data channels; they let engine.recording.replay reproduce a run.

VGR_V1_RECORDING = define_proto(
    "vgr/v1/recording.proto",
    "vgr.v1",
    """
message ServiceExchange {            // one service call as seen by the caller, with its reply
  string caller = 1;                 // calling stage
  string client = 2;                 // its client name (recipe `uses`)
  string provider = 3;
  string service = 4;
  string request_type = 5;
  bytes request = 6;                 // protobuf payload of the request
  uint64 request_seq = 7;
  string reply_type = 8;
  bytes reply = 9;                   // protobuf payload of the reply (empty on error)
  string error = 10;
}
message Delivery {                   // a stage is about to handle message `seq` of input `port`
  string stage = 1;
  string port = 2;
  string source_topic = 3;           // /<stage>/<port> that produced it
  uint64 seq = 4;
}
message StageFinish {                // all inputs of `stage` ended; its finish() runs now
  string stage = 1;
}
message ServedCall {                 // a request a stage served, as seen by the provider
  string provider = 1;
  string service = 2;
  string caller_process = 3;         // empty: the calling session is not one of the run's processes
  string caller_zid = 4;             // the caller's zenoh session (empty: the query did not say)
  string request_type = 5;
  uint64 request_seq = 6;
  string error = 7;                  // why it was not answered; empty when it was
}
""",
)
