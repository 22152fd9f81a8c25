"""The declarative mapping of message fields to protobuf (engine.messages.mapping): a new message type
is a dataclass and a schema; each kind of field round-trips; a misfit fails when it is registered."""

# (no `from __future__ import annotations`: the test types' annotations are objects, resolvable
# wherever pytest imports this file from)

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pytest

from engine import messages as m
from engine import transforms as tf
from engine.messages import codec
from engine.messages.mapping import MappingError, wire_source
from engine.messages.schemas import define_proto

define_proto(
    "vgr/test/mapping.proto",
    "vgrtest",
    """
message Item {
  google.protobuf.Timestamp timestamp = 1;
  string label = 2;
}
message NamedPose {
  string name = 1;
  foxglove.Pose pose = 2;
}
message NamedValue {
  string name = 1;
  double value = 2;
}
message Everything {
  repeated double values = 10;
  google.protobuf.Timestamp timestamp = 1;
  repeated double matrix = 11;
  string frame_id = 2;
  repeated string words = 12;
  string state = 3;
  repeated double numbers = 13;
  uint32 count = 4;
  repeated foxglove.Pose poses = 14;
  bool flag = 5;
  repeated NamedPose named = 15;
  foxglove.Pose pose = 6;
  repeated NamedValue metrics = 16;
  foxglove.Pose maybe = 7;
  string extra_json = 17;
  bool has_other = 8;
  repeated Item items = 18;
  foxglove.Pose other = 9;
  bytes cloud = 19;
}
""",
)


@dataclass(kw_only=True, eq=False)
class Item(m.Message, schema="vgrtest.Item"):
    label: str = ""


@dataclass(kw_only=True, eq=False)
class Everything(m.Message, schema="vgrtest.Everything"):
    BULK: ClassVar[int | None] = 19
    WIRE: ClassVar[m.WireMap] = {
        "T": "pose",
        "state": m.Wire(unset_is_default=True),
        "other": m.Wire(presence="has_other"),
        "matrix": m.Wire(shape=(2, 3)),
        "extra": "extra_json",
        "cloud": m.Wire(dtype="float32", shape=(-1, 3)),
        "local": None,
    }

    state: str = "idle"
    count: int = 0
    flag: bool = False
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    maybe: np.ndarray | None = None
    other: np.ndarray | None = None
    values: np.ndarray | None = None
    matrix: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    words: list[str] = field(default_factory=list)
    numbers: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    named: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    items: list[Item] = field(default_factory=list)
    cloud: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    local: str = "not on the wire"


def roundtrip(msg: m.Message, split: bool = False, monkeypatch: Any = None) -> Any:
    if split:
        monkeypatch.setattr(codec, "SMALL_PAYLOAD", -1)  # the bulk field handed over as a view
    return codec.decode_payload(type(msg), codec.encode_payload(msg))


def test_a_new_message_type_is_a_dataclass_and_a_schema():
    codec.MessageRegistry().add(Everything)  # its code is generated, and checked, where it is registered
    assert (Everything.TYPE, Everything.SCHEMA) == ("Everything", "vgrtest.Everything")  # TYPE: the class name
    assert m.CalibrationResultMsg.TYPE == "CalibrationResult"  # ... unless the class sets another
    assert "def to_proto(self):" in wire_source(Everything) and "self.local" not in wire_source(Everything)


@pytest.mark.parametrize("split", [False, True])
def test_every_kind_of_field_roundtrips(split, monkeypatch):
    T1, T2 = tf.T_from_rotvec([0.1, 0.2, 0.3], [1.0, 2.0, 3.0]), tf.T_from_rotvec([0, 0, 1.0], [0, 0, 0.5])
    msg = Everything(
        stamp_ns=1_700_000_000_000_000_001,
        frame_id="base",
        state="busy",
        count=3,
        flag=True,
        T=T1,
        maybe=T2,
        other=T1,
        values=[1.0, 2.5],
        matrix=np.arange(6.0).reshape(2, 3),
        words=["a", "b"],
        numbers=[np.float32(0.5), 2],
        poses=[T1, T2],
        named={"x": T2, "y": T1},
        metrics={"rms": np.float64(0.25), "n": 4},
        extra={"k": np.arange(2), "z": None},
        items=[Item(label="first", stamp_ns=5), Item(label="second")],
        cloud=np.arange(12, dtype=np.float64).reshape(4, 3),
        local="changed",
    )
    out = roundtrip(msg, split, monkeypatch)
    assert (out.stamp_ns, out.frame_id, out.state, out.count, out.flag) == (msg.stamp_ns, "base", "busy", 3, True)
    for a, b in ((out.T, T1), (out.maybe, T2), (out.other, T1), *zip(out.poses, [T1, T2], strict=True)):
        assert np.allclose(a, b, atol=1e-12)
    assert list(out.named) == ["x", "y"] and np.allclose(out.named["y"], T1, atol=1e-12)
    assert out.values.dtype == np.float64 and out.values.tolist() == [1.0, 2.5]
    assert out.matrix.shape == (2, 3) and np.array_equal(out.matrix, msg.matrix)
    assert out.words == ["a", "b"] and out.numbers == [0.5, 2.0] and out.metrics == {"rms": 0.25, "n": 4.0}
    assert out.extra == {"k": [0, 1], "z": None}
    assert [(i.label, i.stamp_ns) for i in out.items] == [("first", 5), ("second", 0)]
    assert out.cloud.dtype == np.float32 and np.array_equal(out.cloud, msg.cloud)
    assert out.local == "not on the wire"


def test_unset_and_absent_fields_read_as_the_defaults_they_stand_for():
    out = roundtrip(Everything(state=""))
    assert out.state == "idle"  # unset_is_default
    assert out.maybe is None and out.other is None and out.values is None  # absent: None
    assert out.matrix.shape == (2, 3) and not out.matrix.any()
    pb, _ = Everything(maybe=np.eye(4)).to_proto()
    assert pb.HasField("maybe") and not pb.has_other and not pb.HasField("other")


def test_a_hand_written_encoding_may_extend_the_generated_one():
    @dataclass(kw_only=True, eq=False)
    class Counted(Item):
        def to_proto(self):
            pb, bulk = super().to_proto()
            pb.label = pb.label.upper()
            return pb, bulk

    @dataclass(kw_only=True, eq=False)
    class Sub(Counted):
        pass

    assert codec.decode_payload(Counted, codec.encode_payload(Counted(label="ab"))).label == "AB"
    assert Sub.to_proto is Counted.to_proto  # inherited, not replaced by generated code
    assert "pb.label = self.label" in wire_source(Item)


def test_a_field_that_does_not_fit_its_schema_fails_where_it_is_registered():
    @dataclass(kw_only=True, eq=False)
    class Typo(m.Message, schema="vgrtest.Item"):
        lable: str = ""

    @dataclass(kw_only=True, eq=False)
    class Misfit(m.Message, schema="vgrtest.Item"):
        WIRE: ClassVar[m.WireMap] = {"label": "timestamp"}
        label: str = ""

    @dataclass(kw_only=True, eq=False)
    class NotAPose(m.Message, schema="foxglove.PoseInFrame"):
        pose: str = ""

    @dataclass(kw_only=True, eq=False)
    class NoBulk(Item):
        BULK: ClassVar[int | None] = 2

    with pytest.raises(MappingError, match="has no field 'lable'"):
        codec.MessageRegistry().add(Typo)
    with pytest.raises(MappingError, match=r"label -> vgrtest\.Item\.timestamp"):
        codec.MessageRegistry().add(Misfit)
    with pytest.raises(MappingError, match=r"no encoding of <class 'str'> in a foxglove\.Pose field"):
        codec.MessageRegistry().add(NotAPose)
    with pytest.raises(MappingError, match="no field maps to its BULK"):
        codec.MessageRegistry().add(NoBulk)
