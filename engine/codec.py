"""The one codec used on the wire (zenoh) and in recordings (MCAP): protobuf payload + envelope.

Payload
    The message's protobuf encoding (engine.schemas). For messages with one large array
    (``Message.BULK``: point clouds, images, blobs) the encoder serialises the small fields with
    protobuf and appends the array as the length-delimited bulk field itself, so the array is
    copied once; the result is ordinary protobuf that any decoder (Foxglove, C++, Rust) reads. The
    decoder walks the top-level fields and hands the bulk field to numpy as a zero-copy view.

Envelope (zenoh attachment; in MCAP the same values are the channel's schema, the record's
``sequence`` and ``publish_time``)::

    struct "<4sBBHQq": magic b"VGR\\x01", kind, schema version, reserved, seq, stamp_ns
    followed by the UTF-8 message type name (e.g. "PointCloud")

``kind`` is DATA for messages, EOS when a port ends, STOP for local control. Documented in
docs/messages.md.
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import NamedTuple

from engine.messages import BUILTIN_MESSAGE_TYPES, WIRE_CACHE, Message
from engine.schemas import SCHEMA_VERSION, proto_class

__all__ = [
    "Envelope",
    "Kind",
    "MessageRegistry",
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


class Envelope(NamedTuple):
    kind: Kind
    seq: int
    stamp_ns: int
    type_name: str
    schema_version: int = SCHEMA_VERSION


class CodecError(ValueError):
    """A payload or envelope that cannot be decoded."""


def encode_envelope(env: Envelope) -> bytes:
    return _ENV.pack(MAGIC, int(env.kind), env.schema_version, 0, env.seq, env.stamp_ns) + env.type_name.encode()


def decode_envelope(raw: bytes) -> Envelope:
    if len(raw) < _ENV.size:
        raise CodecError(f"envelope too short ({len(raw)} bytes)")
    magic, kind, version, _, seq, stamp = _ENV.unpack_from(raw)
    if magic != MAGIC:
        raise CodecError(f"not a vgr envelope (magic {magic!r})")
    if version > SCHEMA_VERSION:
        raise CodecError(f"schema version {version} is newer than this vgr ({SCHEMA_VERSION}); upgrade vgr")
    return Envelope(Kind(kind), seq, stamp, raw[_ENV.size :].decode(), version)


# --------------------------------------------------------------------------- registry


class MessageRegistry:
    """Message classes by type name; plugins add theirs through the ``vgr_message_types`` hook."""

    def __init__(self) -> None:
        self._types: dict[str, type[Message]] = {}
        for t in BUILTIN_MESSAGE_TYPES:
            self.add(t)

    def add(self, cls: type[Message]) -> None:
        old = self._types.get(cls.TYPE)
        if old is not None and old is not cls:
            raise ValueError(f"message type {cls.TYPE!r} is defined twice ({old.__module__}, {cls.__module__})")
        proto_class(cls.SCHEMA)  # fails early if the schema is unknown
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


def _varint(n: int) -> bytes:
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


def encode_payload(msg: Message) -> bytes:
    """Protobuf bytes of *msg* (bulk array appended as its length-delimited field)."""
    wire = msg.__dict__.get(WIRE_CACHE)  # a published message carries the protobuf it was rebuilt from
    pb, bulk = wire if wire is not None else msg.to_proto()
    head = pb.SerializeToString(deterministic=True)
    if bulk is None or msg.BULK is None:
        return head
    tag = _varint((msg.BULK << 3) | 2) + _varint(len(bulk))
    return b"".join((head, tag, bulk))


def _split_bulk(buf: memoryview, field_number: int) -> tuple[bytes, memoryview | None]:
    """Walk top-level protobuf fields; return (other fields' bytes, bulk field view or None)."""
    parts: list[memoryview] = []
    bulk: memoryview | None = None
    pos, n = 0, len(buf)
    while pos < n:
        start = pos
        key, pos = _read_varint(buf, pos)
        fno, wire = key >> 3, key & 7
        if wire == 0:
            _, pos = _read_varint(buf, pos)
        elif wire == 1:
            pos += 8
        elif wire == 5:
            pos += 4
        elif wire == 2:
            length, pos = _read_varint(buf, pos)
            if pos + length > n:
                raise CodecError("truncated length-delimited field")
            if fno == field_number:
                bulk = buf[pos : pos + length]  # last one wins, as in protobuf
                pos += length
                continue
            pos += length
        else:
            raise CodecError(f"unsupported wire type {wire}")
        if pos > n:
            raise CodecError("truncated field")
        parts.append(buf[start:pos])
    return b"".join(parts), bulk


def decode_payload(cls: type[Message], payload: bytes | memoryview) -> Message:
    """Message of class *cls* from its protobuf bytes (bulk arrays are views of *payload*)."""
    pb = cls.proto()
    try:
        if cls.BULK is None:
            pb.ParseFromString(bytes(payload))
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
