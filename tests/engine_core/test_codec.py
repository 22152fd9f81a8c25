"""The wire codec: round trips, compatibility with standard protobuf / Foxglove decoders, bad bytes."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import Any, ClassVar
from unittest import mock

import numpy as np
import pytest
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud as FoxPointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame as FoxPoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage as FoxRawImage
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import messages as m
from engine import transforms as tf
from engine.messages import codec
from engine.messages.codec import CodecError, Envelope, Kind


def roundtrip(msg: m.Message) -> m.Message:
    payload, env = codec.encode(msg)
    return codec.decode(payload, codec.decode_envelope(env))


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 500),
    st.sampled_from(["float32", "float64"]),
    st.booleans(),
    st.booleans(),
    st.integers(0, 2**62),
    st.integers(1, 2**40),
)
def test_point_cloud_roundtrip_is_exact(n, dtype, with_normals, with_colors, stamp, seq):
    rng = np.random.default_rng(n)
    pc = m.PointCloud(
        points=rng.normal(size=(n, 3)).astype(dtype),
        frame_id="cam",
        stamp_ns=stamp,
        normals=rng.normal(size=(n, 3)) if with_normals else None,
        colors=rng.integers(0, 256, size=(n, 3)) if with_colors else None,
    )
    pc.seq = seq
    out = roundtrip(pc)
    assert isinstance(out, m.PointCloud) and out.seq == seq and out.stamp_ns == stamp and out.frame_id == "cam"
    assert out.points.dtype == np.dtype(dtype) and np.array_equal(out.points, pc.points)
    assert (out.normals is None) == (not with_normals) and (out.colors is None) == (not with_colors)
    if with_normals:
        assert np.array_equal(out.normals, pc.normals)
    if with_colors:
        assert np.array_equal(out.colors, pc.colors)


def test_point_cloud_payload_is_a_standard_foxglove_message():
    pts = np.arange(30, dtype=np.float32).reshape(10, 3)
    payload, _ = codec.encode(m.PointCloud(points=pts, frame_id="camera", stamp_ns=1_500_000_000))
    fox = FoxPointCloud()
    fox.ParseFromString(payload)
    assert fox.frame_id == "camera" and fox.point_stride == 12 and [f.name for f in fox.fields] == ["x", "y", "z"]
    assert fox.timestamp.seconds == 1 and fox.timestamp.nanos == 500_000_000
    assert np.array_equal(np.frombuffer(fox.data, np.float32).reshape(-1, 3), pts)


def test_decoder_reads_foxglove_messages_encoded_by_anyone():
    fox = FoxPointCloud(frame_id="x", point_stride=24, data=np.ones((4, 3)).tobytes())
    for name, off in (("x", 0), ("y", 8), ("z", 16)):
        fox.fields.add(name=name, offset=off, type=8)
    out = codec.decode_payload(m.PointCloud, fox.SerializeToString())
    assert out.points.shape == (4, 3) and np.all(out.points == 1.0)
    img = FoxRawImage(width=3, height=2, encoding="32FC1", step=12, data=np.arange(6, dtype=np.float32).tobytes())
    out_img = codec.decode_payload(m.Image, img.SerializeToString())
    assert out_img.data.shape == (2, 3) and out_img.data[1, 2] == 5.0


def test_pose_uses_foxglove_pose_in_frame():
    T = tf.T_from_rotvec([0.1, -0.2, 0.3], [1.0, 2.0, 3.0])
    payload, _ = codec.encode(m.PoseStamped(T=T, frame_id="base"))
    fox = FoxPoseInFrame()
    fox.ParseFromString(payload)
    assert fox.frame_id == "base" and fox.pose.position.z == 3.0
    assert np.allclose(roundtrip(m.PoseStamped(T=T, frame_id="base")).T, T, atol=1e-15)


EVERY_TYPE = [
    m.Image(data=np.full((4, 5), np.nan, np.float32), frame_id="cam"),
    m.CameraInfo(width=640, height=480, K=np.array([[500, 0, 320], [0, 500, 240], [0, 0, 1.0]])),
    m.Transform(frame_id="base", child_frame_id="tcp", T=tf.T_from_rotvec([0, 0, 1], [0, 0, 1])),
    m.FrameTransforms(transforms=[m.Transform(frame_id="a", child_frame_id="b")]),
    m.JointState(names=["j1", "j2"], positions=np.array([0.1, -0.2]), velocities=np.zeros(2)),
    m.Blob(data=b"\x00\x01" * 100, content_type="application/octet-stream"),
    m.TrackerPose(serial="LHR-1", T=tf.T_from_rotvec([0.1, 0, 0], [0, 1, 0]), valid=False),
    m.Event(level="alarm", code="x", stage="s", message="hello", traceback="tb", details={"a": [1, 2]}),
    m.CalibrationResultMsg(kind="handeye", verdict="ok", transforms={"T_tcp_cam": np.eye(4)}, metrics={"rms_mm": 0.1}),
    m.RobotCommand(command_id="c1", kind="move_j", joints=np.array([0.0, 1.0])),
    m.RobotReply(command_id="c1", ok=True, T=np.eye(4), joints=np.zeros(6), duplicate=True),
    m.Correction(
        kind="delta_tool",
        T=tf.T_from_rotvec([0, 0, 0.01], [0.001, 0, 0]),
        verdict="refused",
        reasons=["r"],
    ),
    m.Request(command="capture", args={"exposure": 3}),
]


@pytest.mark.parametrize("msg", EVERY_TYPE)
def test_every_message_type_roundtrips(msg):
    out = roundtrip(msg)
    assert type(out) is type(msg)
    for k, v in vars(msg).items():
        w = getattr(out, k)
        if k == "seq":
            continue
        if isinstance(v, np.ndarray):
            assert np.allclose(v, w, equal_nan=True, atol=1e-12), k
        elif isinstance(v, list) and v and isinstance(v[0], m.Transform):
            assert len(v) == len(w), k
            for a, b in zip(v, w, strict=True):
                assert np.allclose(a.T, b.T) and (a.frame_id, a.child_frame_id) == (b.frame_id, b.child_frame_id), k
        elif isinstance(v, dict) and v and isinstance(next(iter(v.values())), np.ndarray):
            assert all(np.allclose(v[x], w[x]) for x in v)
        elif isinstance(v, memoryview | bytes):
            assert bytes(v) == bytes(w)
        else:
            assert v == w, k


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200), st.booleans())
def test_garbage_payload_raises_codec_error_only(raw, split):
    """Both decode paths: one protobuf parse (small payloads) and our own walk of the top-level
    fields that hands the bulk field over as a view (``split``: as for payloads above SMALL_PAYLOAD)."""
    with mock.patch.object(codec, "SMALL_PAYLOAD", -1 if split else codec.SMALL_PAYLOAD):
        for cls in (m.PointCloud, m.Image, m.Blob, m.Event, m.PoseStamped):
            with contextlib.suppress(CodecError):
                codec.decode_payload(cls, raw)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([b"\x0a", bytes([(6 << 3) | 2]), b"\x08", b"\xff\xff"]), st.binary(max_size=200))
def test_the_field_walk_refuses_garbage_with_a_codec_error(head, raw):
    """The codec's own walk of a payload's top-level fields (the large-payload path) on a plausible
    first key (a length-delimited field, PointCloud's bulk field, a varint, a long key) followed by
    garbage: it returns or raises CodecError, nothing else (no IndexError from reading past the end)."""
    with contextlib.suppress(CodecError):
        codec._split_bulk(memoryview(head + raw).cast("B"), m.PointCloud.BULK)


@given(st.binary(max_size=60), st.booleans())
def test_garbage_envelope_raises_codec_error_only(raw, with_magic):
    """Random bytes, and random bytes behind a valid magic (to reach the kind, version and name checks)."""
    with contextlib.suppress(CodecError):
        codec.decode_envelope(codec.MAGIC + raw if with_magic else raw)


def test_envelope_roundtrip_and_version_check():
    env = Envelope(Kind.EOS, 42, 123456789, "PointCloud")
    assert codec.decode_envelope(codec.encode_envelope(env)) == env
    newer = codec.encode_envelope(Envelope(Kind.DATA, 1, 1, "Blob", schema_version=99))
    with pytest.raises(CodecError, match="newer"):
        codec.decode_envelope(newer)


def test_unknown_type_name_is_a_codec_error():
    with pytest.raises(CodecError, match="unknown message type"):
        codec.decode(b"", Envelope(Kind.DATA, 1, 1, "NoSuchType"))


def test_bulk_arrays_are_zero_copy_views_of_the_payload():
    pts = np.random.default_rng(0).normal(size=(1000, 3)).astype(np.float32)
    payload, env = codec.encode(m.PointCloud(points=pts))
    out = codec.decode(payload, codec.decode_envelope(env))
    assert not out.points.flags.writeable  # a view of the (immutable) payload: stages must not modify inputs
    assert np.shares_memory(out.points, np.frombuffer(payload, np.uint8))


@pytest.mark.parametrize("msg", [*EVERY_TYPE, m.PointCloud(points=np.ones((5, 3)), frame_id="c", stamp_ns=3)])
def test_payload_is_the_deterministic_protobuf_serialisation(msg):
    """The encoder asks upb for deterministic output only where a map field makes it matter; the
    bytes must be what a deterministic serialisation (bulk field appended) gives."""
    pb, bulk = msg.to_proto()
    expected = pb.SerializeToString(deterministic=True)
    if bulk is not None and msg.BULK is not None:
        expected += codec._varint((msg.BULK << 3) | 2) + codec._varint(len(bulk)) + bytes(bulk)
    assert codec.encode_payload(msg) == expected


def test_a_map_field_is_serialised_deterministically():
    """A message whose protobuf holds a map: upb's plain serialisation orders the entries by its hash
    table (checked below to differ from the sorted order), so the encoder must ask for determinism."""
    from google.protobuf import struct_pb2

    keys = [f"k{i}" for i in range(50)]
    np.random.default_rng(1).shuffle(keys)

    class MapMessage(m.Message):
        TYPE: ClassVar[str] = "MapForDeterminismTest"

        def to_proto(self):
            pb = struct_pb2.Struct()
            for k in keys:
                pb.fields[k].number_value = 1.0
            return pb, None

    pb, _ = MapMessage().to_proto()
    assert pb.SerializeToString() != pb.SerializeToString(deterministic=True)  # the case that matters
    assert codec.encode_payload(MapMessage()) == pb.SerializeToString(deterministic=True)


def test_only_schemas_with_maps_ask_for_deterministic_serialisation():
    from google.protobuf import struct_pb2

    assert codec._has_maps(struct_pb2.Struct) and codec._has_maps(struct_pb2.Value)  # (nested, recursive)
    assert not any(codec._has_maps(type(msg.proto())) for msg in EVERY_TYPE)


@pytest.mark.parametrize(
    "msg",
    [
        m.Blob(data=bytes(range(256)) * 20, frame_id="f", content_type="x", stamp_ns=9),
        m.Image(data=np.arange(64, dtype=np.float32).reshape(8, 8), frame_id="cam", stamp_ns=5),
        m.PointCloud(points=np.arange(30, dtype=np.float32).reshape(10, 3), stamp_ns=2),
        m.PointCloud(points=np.ones((7, 3)), colors=np.full((7, 3), 9, np.uint8)),
    ],
)
def test_small_payloads_parsed_whole_decode_like_large_ones_split(msg, monkeypatch):
    payload = codec.encode_payload(msg)
    assert len(payload) <= codec.SMALL_PAYLOAD  # else both decodes below take the split path
    whole = codec.decode_payload(type(msg), payload)  # small: one protobuf parse
    monkeypatch.setattr(codec, "SMALL_PAYLOAD", -1)
    split = codec.decode_payload(type(msg), payload)  # the large-payload path: bulk field as a view
    for k, v in vars(whole).items():
        w = getattr(split, k)
        if isinstance(v, np.ndarray):
            assert v.dtype == w.dtype and np.array_equal(v, w) and v.flags.writeable == w.flags.writeable, k
        elif isinstance(v, memoryview | bytes):
            assert bytes(v) == bytes(w), k
        else:
            assert v == w, k
    assert codec.encode_payload(whole) == codec.encode_payload(split) == payload


def test_data_format_packs_and_recognises_data_envelopes():
    import struct

    fmt = codec.DataFormat("PointCloud")
    raw = fmt.pack(fmt.head, 7, 1_700_000_000_000_000_001, fmt.name)
    assert raw == codec.encode_envelope(codec.data_envelope(7, 1_700_000_000_000_000_001, "PointCloud"))
    assert codec.decode_envelope(raw) == Envelope(Kind.DATA, 7, 1_700_000_000_000_000_001, "PointCloud")
    head, seq, stamp, name = fmt.unpack(raw)
    assert (head, seq, stamp, name) == (fmt.head, 7, 1_700_000_000_000_000_001, fmt.name)
    # anything else is not taken for this port's data: end of stream, another type, another version
    for other in (
        codec.encode_envelope(Envelope(Kind.EOS, 8, 1, "")),
        codec.encode_envelope(Envelope(Kind.EOS, 8, 1, "PointCloud")),
        codec.encode_envelope(Envelope(Kind.DATA, 8, 1, "Pointcloud")),
        codec.encode_envelope(Envelope(Kind.DATA, 8, 1, "PointCloud", schema_version=0)),
        b"",
    ):
        try:
            head, _, _, name = fmt.unpack(other)
        except struct.error:
            continue
        assert (head, name) != (fmt.head, fmt.name)


def test_freeze_arrays_looks_at_every_field_that_may_hold_an_array() -> None:
    """publish freezes only the fields whose annotation can hold an array; an array in any of them
    (np.ndarray, Any, a dict) is frozen, and fields of strings and bytes are skipped."""

    @dataclass(kw_only=True, eq=False)
    class Mixed(m.Message):
        TYPE: ClassVar[str] = "MixedForFreezeTest"
        label: str = ""
        raw: bytes | memoryview = b""
        arr: np.ndarray = field(default_factory=lambda: np.zeros(3))
        anything: Any = None
        maybe: np.ndarray | None = None

    assert m.array_fields(Mixed) == ("arr", "anything", "maybe")
    assert m.array_fields(m.Blob) == ()
    assert m.array_fields(m.PointCloud) == ("points", "normals", "colors")
    msg = Mixed(arr=np.ones(3), anything=np.ones(2), maybe=None)
    m.freeze_arrays(msg)
    assert not msg.arr.flags.writeable and not msg.anything.flags.writeable
    with pytest.raises(ValueError):
        msg.arr[0] = 5.0
    with pytest.raises(TypeError, match="not a dataclass"):
        m.array_fields(int)
