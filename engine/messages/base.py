"""The base of every message type and what the engine does with any message.

:class:`Message` (stamp, seq, frame id; ``to_proto`` / ``from_proto``; ``BULK`` and ``WIRE_EXACT``),
the helpers message classes share to fill their protobuf (stamps, poses, packed arrays), and the
hand-over rules of publish: :func:`canonical` (what a receiver will see), :func:`detach` and
:func:`freeze_arrays` (a published message is never changed under a consumer's feet).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
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
