"""Message types: the Python objects stages exchange, and their mapping to protobuf schemas.

Every message carries its source's timestamp ``stamp_ns`` (integer ns), a per-port sequence number
``seq`` (set by the publisher) and the ``frame_id`` its geometry is expressed in. Arrays are numpy;
received arrays may be read-only views of the wire buffer, so stages never modify inputs in place.

Each class names its protobuf ``SCHEMA`` (see engine.schemas) and converts with ``to_proto`` /
``from_proto``. A class whose payload is one large array names the bytes field that holds it in
``BULK``: the codec then moves that array without an extra protobuf copy (engine.codec).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, ClassVar, Self

import numpy as np

from engine import transforms as tf
from engine.schemas import ProtoMessage, proto_class

Bulk = memoryview | bytes | None


def _bytes_of(arr: np.ndarray) -> memoryview:
    """Flat uint8 view of a C-contiguous array (copies only when the array is not contiguous)."""
    return memoryview(np.ascontiguousarray(arr).reshape(-1).view(np.uint8))


_PACKED_TYPES = {  # foxglove.PackedElementField.NumericType
    np.dtype("uint8"): 1,
    np.dtype("int8"): 2,
    np.dtype("uint16"): 3,
    np.dtype("int16"): 4,
    np.dtype("uint32"): 5,
    np.dtype("int32"): 6,
    np.dtype("float32"): 7,
    np.dtype("float64"): 8,
}
_PACKED_DTYPES = {v: k for k, v in _PACKED_TYPES.items()}


# --------------------------------------------------------------------------- proto helpers
# Public: plugins defining their own message types (engine.schemas.define_proto) use them too.


def set_stamp(pb: Any, stamp_ns: int) -> None:
    ts = pb.timestamp  # (each attribute access of a sub-message builds a new wrapper)
    ts.seconds, ts.nanos = divmod(int(stamp_ns), 1_000_000_000)


def get_stamp(pb: Any) -> int:
    ts = pb.timestamp
    return ts.seconds * 1_000_000_000 + ts.nanos  # (protobuf integer fields read as int)


def set_pose(pose_pb: Any, T: np.ndarray) -> None:
    T = np.asarray(T, dtype=float)
    p, q = T[:3, 3], tf.quat_xyzw_from_R(T[:3, :3])
    pose_pb.position.x, pose_pb.position.y, pose_pb.position.z = (float(v) for v in p)
    o = pose_pb.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in q)


def get_pose(pose_pb: Any) -> np.ndarray:
    p, o = pose_pb.position, pose_pb.orientation
    if (o.x, o.y, o.z, o.w) == (0.0, 0.0, 0.0, 0.0):
        return tf.T_from_Rt(np.eye(3), (p.x, p.y, p.z))  # unset orientation means identity
    return tf.T_from_pose7((p.x, p.y, p.z), (o.x, o.y, o.z, o.w))


# --------------------------------------------------------------------------- base


@dataclass(kw_only=True, eq=False)
class Message:
    """Base of every message type."""

    TYPE: ClassVar[str] = "Message"
    SCHEMA: ClassVar[str] = ""
    BULK: ClassVar[int | None] = None  # protobuf field number carrying the bulk array, if any
    # True when from_proto(to_proto(m)) reproduces m bit for bit (raw arrays, strings, JSON): publish
    # then hands the object over as is. False (poses travel as quaternions, which round by an ulp):
    # publish hands over the wire form, so a local consumer, a remote one and a replay see the same.
    WIRE_EXACT: ClassVar[bool] = False
    _pb_class: ClassVar[Any] = None  # protobuf class of SCHEMA, looked up on first use (per class)

    stamp_ns: int = 0
    seq: int = 0
    frame_id: str = ""

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        """Protobuf message *without* the bulk field, and the bulk bytes (or None)."""
        raise NotImplementedError

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        raise NotImplementedError

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._pb_class = None  # each class looks up its own SCHEMA (a subclass may name another)

    @classmethod
    def proto(cls) -> Any:
        """A new, empty protobuf message of this class's schema (class looked up once)."""
        pb_cls = cls._pb_class
        if pb_cls is None:
            pb_cls = cls._pb_class = proto_class(cls.SCHEMA)
        return pb_cls()


WIRE_CACHE = "_wire"  # attribute holding (protobuf, bulk) of a canonical message; see canonical()


def canonical(msg: Message) -> Message:
    """*msg* as a receiver on the wire (or a replay of the recording) sees it: for types that are
    not ``WIRE_EXACT``, rebuilt from its protobuf form (no serialisation; the bulk buffer is shared)."""
    if msg.WIRE_EXACT:
        return msg
    pb, bulk = msg.to_proto()
    new = type(msg).from_proto(pb, bulk)
    new.seq = msg.seq
    # the wire form itself travels along: a quaternion -> matrix -> quaternion round trip is not
    # always a fixed point, so re-encoding `new` could give other bytes than the ones it came from
    new.__dict__[WIRE_CACHE] = (pb, bulk)
    return new


def freeze(msg: Message) -> Message:
    """Make *msg* safe to hand to several consumers: its numpy arrays become read-only.

    A message that was already published (``seq`` set, e.g. a received message passed on) is
    shallow-copied first, so re-publishing never changes what another consumer holds. Arrays are
    frozen in place: a producer that writes into an array after publishing it gets an error
    instead of silently corrupting a consumer. (The two steps are also :func:`detach` and
    :func:`freeze_arrays`, which publish runs apart.)
    """
    msg = detach(msg)
    freeze_arrays(msg)
    return msg


def detach(msg: Message) -> Message:
    """*msg*, or a shallow copy of it if it was already published (``seq`` set)."""
    if msg.seq:
        new = object.__new__(type(msg))
        new.__dict__.update(msg.__dict__)
        new.__dict__.pop(WIRE_CACHE, None)  # a re-published message may have been changed: encode it anew
        msg = new
    return msg


def freeze_arrays(msg: Message) -> None:
    """Make the numpy arrays among *msg*'s fields read-only, in place.

    Only the fields that can hold an array are looked at (:func:`array_fields`, once per class):
    publish calls this for every message, and for a message of strings and bytes the scan of all its
    attributes cost more than the rest of the hand-over to a local consumer."""
    cls = type(msg)
    names = _ARRAY_FIELDS.get(cls)
    if names is None:
        names = array_fields(cls)
    if names:
        d = msg.__dict__
        for name in names:
            v = d.get(name)
            if isinstance(v, _ndarray) and v.flags.writeable:
                v.flags.writeable = False


_ndarray = np.ndarray
_ARRAY_FIELDS: dict[type, tuple[str, ...]] = {}
# annotations of fields that cannot hold a numpy array; any other annotation (np.ndarray, Any, a
# custom class, ...) is looked at when the message is published
_NO_ARRAY = frozenset({"str", "int", "float", "bool", "bytes", "memoryview", "bytearray", "None"})


def array_fields(cls: type) -> tuple[str, ...]:
    """Names of the dataclass fields of *cls* that may hold a numpy array (cached per class)."""
    if not is_dataclass(cls):
        raise TypeError(f"{cls.__name__} is not a dataclass message type")
    names = []
    for f in fields(cls):
        ann = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", repr(f.type))
        if not all(part.strip() in _NO_ARRAY for part in ann.split("|")):
            names.append(f.name)
    out = _ARRAY_FIELDS[cls] = tuple(names)
    return out


# --------------------------------------------------------------------------- geometry (Foxglove)


@dataclass(kw_only=True, eq=False)
class PointCloud(Message):
    """Unorganised point cloud: ``points`` (N, 3) float32/float64 in ``frame_id``, optional
    ``normals`` (N, 3) of the same dtype and ``colors`` (N, 3) uint8. Schema foxglove.PointCloud."""

    TYPE: ClassVar[str] = "PointCloud"
    WIRE_EXACT: ClassVar[bool] = True
    SCHEMA: ClassVar[str] = "foxglove.PointCloud"
    BULK: ClassVar[int | None] = 6

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"PointCloud.points must be (N, 3), got {self.points.shape}")
        if self.points.dtype not in (np.float32, np.float64):
            self.points = self.points.astype(np.float64)
        if self.normals is not None:
            self.normals = np.asarray(self.normals, dtype=self.points.dtype)
            if self.normals.shape != self.points.shape:
                raise ValueError("PointCloud.normals must have the shape of points")
        if self.colors is not None:
            self.colors = np.asarray(self.colors, dtype=np.uint8)
            if self.colors.shape != self.points.shape:
                raise ValueError("PointCloud.colors must be (N, 3) uint8")

    def _layout(self) -> list[tuple[str, np.ndarray, int]]:
        cols: list[tuple[str, np.ndarray, int]] = [
            ("x", self.points, 0),
            ("y", self.points, 1),
            ("z", self.points, 2),
        ]
        if self.normals is not None:
            cols += [
                ("normal_x", self.normals, 0),
                ("normal_y", self.normals, 1),
                ("normal_z", self.normals, 2),
            ]
        if self.colors is not None:
            cols += [("red", self.colors, 0), ("green", self.colors, 1), ("blue", self.colors, 2)]
        return cols

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id = self.frame_id
        pb.pose.orientation.w = 1.0
        cols = self._layout()
        dtype = np.dtype([(name, arr.dtype) for name, arr, _ in cols])
        offset = 0
        for name, arr, _ in cols:
            pb.fields.add(name=name, offset=offset, type=_PACKED_TYPES[arr.dtype])
            offset += arr.dtype.itemsize
        pb.point_stride = dtype.itemsize
        if len(cols) == 3 and self.points.flags.c_contiguous:
            return pb, _bytes_of(self.points)
        packed = np.empty(len(self.points), dtype=dtype)
        for name, arr, k in cols:
            packed[name] = arr[:, k]
        return pb, _bytes_of(packed)

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        data = bulk if bulk is not None else pb.data
        names = [f.name for f in pb.fields]
        dtype = np.dtype(
            {
                "names": names,
                "formats": [_PACKED_DTYPES[f.type] for f in pb.fields],
                "offsets": [f.offset for f in pb.fields],
                "itemsize": pb.point_stride,
            }
        )
        n = len(data) // pb.point_stride if pb.point_stride else 0
        xyz_t = dtype.fields["x"][0] if "x" in names else np.dtype(np.float32)
        if names == ["x", "y", "z"] and pb.point_stride == 3 * xyz_t.itemsize:
            points = np.frombuffer(data, dtype=xyz_t).reshape(n, 3)
            return cls(stamp_ns=get_stamp(pb), frame_id=pb.frame_id, points=points)
        rec = np.frombuffer(data, dtype=dtype, count=n)

        def stack(keys: tuple[str, str, str]) -> np.ndarray | None:
            if not all(k in names for k in keys):
                return None
            return np.stack([rec[k] for k in keys], axis=1)

        pts = stack(("x", "y", "z"))
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            points=pts if pts is not None else np.zeros((n, 3)),
            normals=stack(("normal_x", "normal_y", "normal_z")),
            colors=stack(("red", "green", "blue")),
        )


_IMAGE_ENCODINGS = {
    "32FC1": (np.float32, 1),
    "64FC1": (np.float64, 1),
    "16UC1": (np.uint16, 1),
    "mono8": (np.uint8, 1),
    "rgb8": (np.uint8, 3),
    "bgr8": (np.uint8, 3),
}


@dataclass(kw_only=True, eq=False)
class Image(Message):
    """Raw image (H, W) or (H, W, C). Depth images use encoding ``32FC1`` in metres with NaN for
    invalid pixels. Schema foxglove.RawImage."""

    TYPE: ClassVar[str] = "Image"
    WIRE_EXACT: ClassVar[bool] = True
    SCHEMA: ClassVar[str] = "foxglove.RawImage"
    BULK: ClassVar[int | None] = 6

    data: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    encoding: str = "32FC1"

    def __post_init__(self) -> None:
        if self.encoding not in _IMAGE_ENCODINGS:
            raise ValueError(f"unsupported image encoding {self.encoding!r}; use one of {sorted(_IMAGE_ENCODINGS)}")
        dt, ch = _IMAGE_ENCODINGS[self.encoding]
        self.data = np.asarray(self.data, dtype=dt)
        if (ch == 1 and self.data.ndim != 2) or (ch > 1 and (self.data.ndim != 3 or self.data.shape[2] != ch)):
            raise ValueError(f"image data shape {self.data.shape} does not fit encoding {self.encoding}")

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id = self.frame_id
        h, w = self.data.shape[:2]
        pb.width, pb.height, pb.encoding = w, h, self.encoding
        pb.step = w * self.data.itemsize * (self.data.shape[2] if self.data.ndim == 3 else 1)
        return pb, _bytes_of(self.data)

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        dt, ch = _IMAGE_ENCODINGS[pb.encoding]
        buf = bulk if bulk is not None else pb.data
        shape = (pb.height, pb.width) if ch == 1 else (pb.height, pb.width, ch)
        data = np.frombuffer(buf, dtype=dt).reshape(shape)
        return cls(stamp_ns=get_stamp(pb), frame_id=pb.frame_id, data=data, encoding=pb.encoding)


@dataclass(kw_only=True, eq=False)
class CameraInfo(Message):
    """Pinhole intrinsics of a camera (no distortion unless D is given). Schema foxglove.CameraCalibration."""

    TYPE: ClassVar[str] = "CameraInfo"
    SCHEMA: ClassVar[str] = "foxglove.CameraCalibration"

    width: int = 0
    height: int = 0
    K: np.ndarray = field(default_factory=lambda: np.eye(3))
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = "plumb_bob"

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.width, pb.height = self.frame_id, self.width, self.height
        pb.distortion_model = self.distortion_model
        K = np.asarray(self.K, dtype=float)
        pb.K.extend(K.ravel().tolist())
        pb.D.extend(np.asarray(self.D, dtype=float).ravel().tolist())
        pb.R.extend(np.eye(3).ravel().tolist())
        P = np.zeros((3, 4))
        P[:, :3] = K
        pb.P.extend(P.ravel().tolist())
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            width=pb.width,
            height=pb.height,
            K=np.array(pb.K, dtype=float).reshape(3, 3),
            D=np.array(pb.D, dtype=float),
            distortion_model=pb.distortion_model,
        )


@dataclass(kw_only=True, eq=False)
class PoseStamped(Message):
    """Pose ``T`` (4x4) of an entity in ``frame_id``. Schema foxglove.PoseInFrame."""

    TYPE: ClassVar[str] = "PoseStamped"
    SCHEMA: ClassVar[str] = "foxglove.PoseInFrame"

    T: np.ndarray = field(default_factory=lambda: np.eye(4))

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id = self.frame_id
        set_pose(pb.pose, self.T)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(stamp_ns=get_stamp(pb), frame_id=pb.frame_id, T=get_pose(pb.pose))


@dataclass(kw_only=True, eq=False)
class Transform(Message):
    """``T`` = T_parent_child with parent ``frame_id``. Schema foxglove.FrameTransform."""

    TYPE: ClassVar[str] = "Transform"
    SCHEMA: ClassVar[str] = "foxglove.FrameTransform"

    child_frame_id: str = ""
    T: np.ndarray = field(default_factory=lambda: np.eye(4))

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        _fill_frame_transform(pb, self)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(**_read_frame_transform(pb))


def _fill_frame_transform(pb: Any, t: Transform) -> None:
    set_stamp(pb, t.stamp_ns)
    pb.parent_frame_id, pb.child_frame_id = t.frame_id, t.child_frame_id
    T = np.asarray(t.T, dtype=float)
    p, q = T[:3, 3], tf.quat_xyzw_from_R(T[:3, :3])
    pb.translation.x, pb.translation.y, pb.translation.z = (float(v) for v in p)
    pb.rotation.x, pb.rotation.y, pb.rotation.z, pb.rotation.w = (float(v) for v in q)


def _read_frame_transform(pb: Any) -> dict[str, Any]:
    r, t = pb.rotation, pb.translation
    T = (
        tf.T_from_pose7((t.x, t.y, t.z), (r.x, r.y, r.z, r.w))
        if (r.x, r.y, r.z, r.w) != (0, 0, 0, 0)
        else (tf.T_from_Rt(np.eye(3), (t.x, t.y, t.z)))
    )
    return {
        "stamp_ns": get_stamp(pb),
        "frame_id": pb.parent_frame_id,
        "child_frame_id": pb.child_frame_id,
        "T": T,
    }


@dataclass(kw_only=True, eq=False)
class FrameTransforms(Message):
    """A set of transforms (the frame tree of the cell). Schema foxglove.FrameTransforms."""

    TYPE: ClassVar[str] = "FrameTransforms"
    SCHEMA: ClassVar[str] = "foxglove.FrameTransforms"

    transforms: list[Transform] = field(default_factory=list)

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        for t in self.transforms:
            _fill_frame_transform(pb.transforms.add(), t)
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        ts = [Transform(**_read_frame_transform(t)) for t in pb.transforms]
        return cls(stamp_ns=ts[0].stamp_ns if ts else 0, transforms=ts)


@dataclass(kw_only=True, eq=False)
class JointState(Message):
    """Joint positions (rad or m), velocities and efforts by joint name. Schema foxglove.JointStates."""

    TYPE: ClassVar[str] = "JointState"
    SCHEMA: ClassVar[str] = "foxglove.JointStates"

    names: list[str] = field(default_factory=list)
    positions: np.ndarray = field(default_factory=lambda: np.zeros(0))
    velocities: np.ndarray | None = None
    efforts: np.ndarray | None = None

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        n = len(self.positions)
        names = self.names or [f"joint{i + 1}" for i in range(n)]
        for i in range(n):
            j = pb.joints.add(name=names[i], position=float(self.positions[i]))
            if self.velocities is not None:
                j.velocity = float(self.velocities[i])
            if self.efforts is not None:
                j.effort = float(self.efforts[i])
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        js = list(pb.joints)
        return cls(
            stamp_ns=get_stamp(pb),
            names=[j.name for j in js],
            positions=np.array([j.position for j in js]),
            velocities=np.array([j.velocity for j in js]) if js and js[0].HasField("velocity") else None,
            efforts=np.array([j.effort for j in js]) if js and js[0].HasField("effort") else None,
        )


@dataclass
class Mesh:
    """A triangle mesh attached to a frame, for the 3D view (``vertices`` (N, 3) m, ``triangles`` (M, 3))."""

    id: str
    frame_id: str
    vertices: np.ndarray
    triangles: np.ndarray
    color: tuple[float, float, float, float] = (0.6, 0.6, 0.65, 1.0)


@dataclass(kw_only=True, eq=False)
class SceneMeshes(Message):
    """Meshes of the cell (workpieces, fixtures) for Foxglove's 3D view. Schema foxglove.SceneUpdate."""

    TYPE: ClassVar[str] = "SceneMeshes"
    SCHEMA: ClassVar[str] = "foxglove.SceneUpdate"

    meshes: list[Mesh] = field(default_factory=list)

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        for m in self.meshes:
            ent = pb.entities.add(frame_id=m.frame_id, id=m.id, frame_locked=True)
            ent.timestamp.seconds, ent.timestamp.nanos = divmod(int(self.stamp_ns), 1_000_000_000)
            tri = ent.triangles.add()
            tri.pose.orientation.w = 1.0
            v = np.asarray(m.vertices, dtype=float)[np.asarray(m.triangles, dtype=np.int64).reshape(-1)]
            for x, y, z in v.tolist():
                tri.points.add(x=x, y=y, z=z)
            tri.color.r, tri.color.g, tri.color.b, tri.color.a = m.color
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        meshes = []
        stamp = 0
        for ent in pb.entities:
            stamp = stamp or int(ent.timestamp.seconds) * 1_000_000_000 + int(ent.timestamp.nanos)
            for tri in ent.triangles:
                pts = np.array([(p.x, p.y, p.z) for p in tri.points], dtype=float).reshape(-1, 3)
                c = tri.color
                meshes.append(Mesh(ent.id, ent.frame_id, pts, np.arange(len(pts)).reshape(-1, 3), (c.r, c.g, c.b, c.a)))
        return cls(stamp_ns=stamp, meshes=meshes)


# --------------------------------------------------------------------------- vgr.v1


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
    SceneMeshes,
)
