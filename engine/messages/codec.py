"""The one codec used on the wire (zenoh) and in recordings (MCAP): protobuf payload + envelope.

Payload
    The message's protobuf encoding (engine.messages.schemas). For messages with one large array
    (``Message.BULK``: point clouds, images, blobs) the encoder serialises the small fields with
    protobuf and appends the array as the length-delimited bulk field itself, so the array is
    copied once; the result is ordinary protobuf that any decoder (Foxglove, C++, Rust) reads. The
    decoder walks the top-level fields and hands the bulk field to numpy as a zero-copy view.

Envelope (zenoh attachment; in MCAP the same values are the channel's schema, the record's
``sequence`` and ``publish_time``)::

    struct "<4sBBHQq": magic b"VGR\\x01", kind, schema version, reserved, seq, stamp_ns
    followed by the UTF-8 message type name (e.g. "PointCloud")

``kind`` is DATA for messages, EOS when a port ends, STOP for local control, BATCH for a sample
holding several messages (only on the internal stage-to-stage key, see engine.transport.wire), VIEW for
a sample whose payload names a block of the sender's shared memory (same key, same host only:
engine.transport.shm_views). Documented in
docs/messages.md.
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import Any, NamedTuple

from engine.messages import BUILTIN_MESSAGE_TYPES, WIRE_CACHE, Message
from engine.messages.mapping import generate_now
from engine.messages.schemas import SCHEMA_VERSION, proto_class

__all__ = [
    "DataFormat",
    "Envelope",
    "Kind",
    "MessageRegistry",
    "data_envelope",
    "decode",
    "decode_envelope",
    "encode",
    "encode_envelope",
    "registry",
]

MAGIC = b"VGR\x01"
_ENV = struct.Struct("<4sBBHQq")


class Kind(IntEnum):
    DATA = 0
    EOS = 1
    STOP = 2
    BATCH = 3  # several messages in one sample, between vgr processes (engine.transport.wire)
    VIEW = 4  # a descriptor of a payload in the sender's shared memory, same host (engine.transport.shm_views)


class Envelope(NamedTuple):
    kind: Kind
    seq: int
    stamp_ns: int
    type_name: str
    schema_version: int = SCHEMA_VERSION


class CodecError(ValueError):
    """A payload or envelope that cannot be decoded."""


_new_envelope = tuple.__new__


def data_envelope(seq: int, stamp_ns: int, type_name: str) -> Envelope:
    """``Envelope(Kind.DATA, seq, stamp_ns, type_name)``, built without the NamedTuple constructor's
    argument handling (the publish path makes one per message)."""
    return _new_envelope(Envelope, (Kind.DATA, seq, stamp_ns, type_name, SCHEMA_VERSION))


_pack, _unpack_from, _ENV_SIZE = _ENV.pack, _ENV.unpack_from, _ENV.size
_KINDS = tuple(Kind)  # Kind(k) through the Enum machinery costs more than the rest of the decode
_NAMES: dict[bytes, str] = {}  # type names seen on the wire, decoded (bounded: see decode_envelope)


def encode_envelope(env: Envelope) -> bytes:
    return _pack(MAGIC, env.kind, env.schema_version, 0, env.seq, env.stamp_ns) + env.type_name.encode()


class DataFormat:
    """The envelope of one message type's DATA messages, for the hot paths of one port.

    ``pack(head, seq, stamp_ns, name)`` builds the envelope in one struct call (what
    ``encode_envelope(data_envelope(...))`` gives); ``unpack(raw)`` splits one into
    ``(head, seq, stamp_ns, name)`` and raises ``struct.error`` when the length does not fit. A
    received envelope whose ``head`` and ``name`` equal this format's is a DATA message of this type
    at this schema version; anything else (end of stream, an older version, another type, garbage)
    goes through :func:`decode_envelope`."""

    __slots__ = ("head", "name", "pack", "type_name", "unpack")

    def __init__(self, type_name: str) -> None:
        self.type_name = type_name
        self.name = type_name.encode()
        fmt = struct.Struct(f"<8sQq{len(self.name)}s")
        self.head = _pack(MAGIC, Kind.DATA, SCHEMA_VERSION, 0, 0, 0)[:8]
        self.pack, self.unpack = fmt.pack, fmt.unpack


def decode_envelope(raw: bytes) -> Envelope:
    if len(raw) < _ENV_SIZE:
        raise CodecError(f"envelope too short ({len(raw)} bytes)")
    magic, kind, version, _, seq, stamp = _unpack_from(raw)
    if magic != MAGIC:
        raise CodecError(f"not a vgr envelope (magic {magic!r})")
    if version > SCHEMA_VERSION:
        raise CodecError(f"schema version {version} is newer than this vgr ({SCHEMA_VERSION}); upgrade vgr")
    if kind >= len(_KINDS):
        raise CodecError(f"unknown envelope kind {kind}")
    raw_name = raw[_ENV_SIZE:]
    name = _NAMES.get(raw_name)
    if name is None:
        try:
            name = raw_name.decode()
        except UnicodeDecodeError as exc:
            raise CodecError(f"envelope type name is not UTF-8: {exc}") from None
        if len(_NAMES) < 4096:
            _NAMES[raw_name] = name
    return _new_envelope(Envelope, (_KINDS[kind], seq, stamp, name, version))


# --------------------------------------------------------------------------- registry


class MessageRegistry:
    """Message classes by type name; plugins add theirs through the ``vgr_message_types`` hook."""

    def __init__(self) -> None:
        self._types: dict[str, type[Message]] = {}
        for t in BUILTIN_MESSAGE_TYPES:  # (their mappings are written on first use; a test checks them all)
            self.add(t, generate=False)

    def add(self, cls: type[Message], *, generate: bool = True) -> None:
        old = self._types.get(cls.TYPE)
        if old is not None and old is not cls:
            raise ValueError(f"message type {cls.TYPE!r} is defined twice ({old.__module__}, {cls.__module__})")
        proto_class(cls.SCHEMA)  # fails early if the schema is unknown
        if generate:
            generate_now(cls)  # ... or if its fields do not fit it (engine.messages.mapping)
        self._types[cls.TYPE] = cls

    def get(self, name: str) -> type[Message]:
        try:
            return self._types[name]
        except KeyError:
            raise CodecError(f"unknown message type {name!r}") from None

    def names(self) -> list[str]:
        return sorted(self._types)

    def __contains__(self, name: str) -> bool:
        return name in self._types


registry = MessageRegistry()


# --------------------------------------------------------------------------- payload


_SMALL_VARINTS = tuple(bytes((i,)) for i in range(0x80))


def _varint(n: int) -> bytes:
    if n < 0x80:
        return _SMALL_VARINTS[n]
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _read_varint(buf: memoryview, pos: int) -> tuple[int, int]:
    shift = result = 0
    while True:
        if pos >= len(buf):
            raise CodecError("truncated varint")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise CodecError("varint too long")


def encode_parts(msg: Message) -> tuple[bytes, bytes | memoryview | None]:
    """*msg*'s protobuf bytes in two parts, ``(head, bulk)``: their concatenation is
    :func:`encode_payload`'s result; *bulk* is the bulk field's contents, not copied (the message's
    bytes, or a view of its array), or None when the message has no bulk field to append. A sender
    that writes the two parts where they go (engine.transport.shm) saves the copy that joining them costs."""
    wire = msg.__dict__.get(WIRE_CACHE)  # a published message carries the protobuf it was rebuilt from
    pb, bulk = wire if wire is not None else msg.to_proto()
    maps = _MAPS.get(type(pb))
    if maps is None:
        maps = _has_maps(type(pb))
    head = pb.SerializeToString(deterministic=True) if maps else pb.SerializeToString()
    if bulk is None or msg.BULK is None:
        return head, None
    key = _BULK_KEYS.get(msg.BULK)
    if key is None:
        key = _BULK_KEYS[msg.BULK] = _varint((msg.BULK << 3) | 2)
    return b"".join((head, key, _varint(len(bulk)))), bulk


def encode_payload(msg: Message) -> bytes:
    """Protobuf bytes of *msg* (bulk array appended as its length-delimited field)."""
    head, bulk = encode_parts(msg)
    return head if bulk is None else b"".join((head, bulk))


_BULK_KEYS: dict[int, bytes] = {}  # field number -> encoded key of the length-delimited bulk field
_MAPS: dict[type, bool] = {}  # protobuf class -> whether a map field occurs anywhere in it


def _has_maps(pb_cls: type) -> bool:
    """True when messages of *pb_cls* may contain a map field, whose entries only deterministic
    serialisation orders. Without maps the two serialisations are the same bytes, and asking for
    ``deterministic=True`` costs more than the serialisation of a small message itself."""
    known = _MAPS.get(pb_cls)
    if known is None:
        known = _MAPS[pb_cls] = _descriptor_has_maps(pb_cls.DESCRIPTOR, set())  # type: ignore[attr-defined]
    return known


def _descriptor_has_maps(desc: Any, seen: set[str]) -> bool:
    seen.add(desc.full_name)
    for f in desc.fields:
        sub = f.message_type
        if sub is None:
            continue
        if sub.GetOptions().map_entry:
            return True
        if sub.full_name not in seen and _descriptor_has_maps(sub, seen):
            return True
    return False


def _split_bulk(buf: memoryview, field_number: int) -> tuple[bytes | memoryview, memoryview | None]:
    """Walk top-level protobuf fields; return (other fields' bytes, bulk field view or None).

    Single-byte keys and lengths (nearly all of them) are read inline; the other fields are kept
    as ranges of *buf*, joined only when the bulk field sits between them (our encoder puts it last,
    so the rest is normally one slice: no copy)."""
    bulk: memoryview | None = None
    pieces: list[memoryview] = []
    keep_from = 0  # start of the range of other fields not yet kept
    pos, n = 0, len(buf)
    while pos < n:
        start = pos
        key = buf[pos]
        if key < 0x80:
            pos += 1
        else:
            key, pos = _read_varint(buf, pos)
        wire = key & 7
        if wire == 2:
            if pos < n and buf[pos] < 0x80:
                length = buf[pos]
                pos += 1
            else:
                length, pos = _read_varint(buf, pos)
            end = pos + length
            if end > n:
                raise CodecError("truncated length-delimited field")
            if key >> 3 == field_number:
                if start > keep_from:
                    pieces.append(buf[keep_from:start])
                bulk = buf[pos:end]  # last one wins, as in protobuf
                keep_from = end
            pos = end
            continue
        if wire == 0:
            _, pos = _read_varint(buf, pos)
        elif wire == 1:
            pos += 8
        elif wire == 5:
            pos += 4
        else:
            raise CodecError(f"unsupported wire type {wire}")
        if pos > n:
            raise CodecError("truncated field")
    if keep_from < n:
        pieces.append(buf[keep_from:n])
    if len(pieces) == 1:
        return pieces[0], bulk
    return b"".join(pieces), bulk


SMALL_PAYLOAD = 8192  # below this, one protobuf parse (copying the bulk) beats walking the fields in Python


def decode_payload(cls: type[Message], payload: bytes | memoryview) -> Message:
    """Message of class *cls* from its protobuf bytes (bulk arrays of payloads larger than
    SMALL_PAYLOAD are views of *payload*; smaller ones are parsed whole, the bulk field copied)."""
    pb = cls.proto()
    try:
        if cls.BULK is None or len(payload) <= SMALL_PAYLOAD:
            pb.ParseFromString(payload if type(payload) is bytes else bytes(payload))
            return cls.from_proto(pb, None)
        rest, bulk = _split_bulk(memoryview(payload).cast("B"), cls.BULK)
        pb.ParseFromString(rest)
        return cls.from_proto(pb, bulk)
    except CodecError:
        raise
    except Exception as exc:  # protobuf DecodeError, shape errors from a malformed sender
        raise CodecError(f"cannot decode {cls.TYPE}: {exc}") from exc


def encode(msg: Message) -> tuple[bytes, bytes]:
    """(payload, envelope) of a data message."""
    env = Envelope(Kind.DATA, msg.seq, msg.stamp_ns, msg.TYPE)
    return encode_payload(msg), encode_envelope(env)


def decode(payload: bytes | memoryview, envelope: Envelope) -> Message:
    """Message from a payload and its envelope (seq and stamp taken from the envelope)."""
    msg = decode_payload(registry.get(envelope.type_name), payload)
    msg.seq = envelope.seq
    if not msg.stamp_ns:
        msg.stamp_ns = envelope.stamp_ns
    return msg
