"""The base of every message type and what the engine does with any message.

:class:`Message` (stamp, seq, frame id; ``to_proto`` / ``from_proto``, generated from the class's
fields by engine.messages.mapping; ``BULK`` and ``WIRE_EXACT``) and the hand-over rules of publish:
:func:`canonical` (what a receiver will see), :func:`detach` and :func:`freeze_arrays` (a published
message is never changed under a consumer's feet).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
from typing import Any, ClassVar, Self

import numpy as np

from engine.messages.mapping import Bulk, WireMap, codec_of, install, mapped
from engine.messages.schemas import ProtoMessage, proto_class


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
    # dataclass field -> protobuf field name, Wire options, or None (not on the wire); merged along
    # the bases. Fields not named here travel in the field of their name (engine.messages.mapping).
    WIRE: ClassVar[WireMap] = {"stamp_ns": "timestamp", "seq": None}
    _pb_class: ClassVar[Any] = None  # protobuf class of SCHEMA, looked up on first use (per class)

    stamp_ns: int = 0
    seq: int = 0
    frame_id: str = ""

    @mapped
    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        """Protobuf message *without* the bulk field, and the bulk bytes (or None). Generated from
        the class's fields and ``WIRE`` unless the class writes its own (which may call this)."""
        return codec_of(type(self)).to_proto(self)

    @classmethod
    @mapped
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        """The message of protobuf *pb* (whose bulk field, if split off, is *bulk*)."""
        result: Self = codec_of(cls).from_proto(cls, pb, bulk)
        return result

    def __init_subclass__(cls, *, schema: str | None = None, **kwargs: Any) -> None:
        """``class Pose(Message, schema="foxglove.PoseInFrame")``: a message type, named ``TYPE`` on
        the wire (its class name unless it sets another), carried by protobuf ``SCHEMA``."""
        super().__init_subclass__(**kwargs)
        if schema is not None:
            cls.SCHEMA = schema
        if "TYPE" not in cls.__dict__:
            cls.TYPE = cls.__name__
        cls._pb_class = None  # each class looks up its own SCHEMA (a subclass may name another)
        install(cls)  # its generated to_proto / from_proto, written on first use

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
