"""Malformed and odd PointCloud2 messages (hypothesis): a cloud either converts to exactly the points
a per-point reading of its bytes gives, or is refused with a ConversionError naming the topic;
nothing else escapes (no IndexError, no numpy error, no crash) from the dataclass or from CDR."""

from __future__ import annotations

import struct

import numpy as np
import pytest

pytest.importorskip("rosbags")

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ros_msgs import header, point_field

from plugins.ros2.convert import ConversionError, decode, from_ros
from plugins.ros2.convert_common import ros_class, typestore

CLOUD = "sensor_msgs/msg/PointCloud2"
NAMES = ["x", "y", "z", "intensity", "rgb", "r", "g", "b", "normal_x", "normal_y", "normal_z", "ring"]
SIZES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}
FORMATS = {7: "f", 8: "d"}


@st.composite
def clouds(draw: st.DrawFn) -> object:
    """A well-formed cloud (x, y, z float32 or float64 in any order, other fields, padding, rows,
    either byte order), then, mostly, one thing broken: a field, the steps, the data's length."""
    xyz_type = draw(st.sampled_from([7, 8]))
    extra = draw(st.lists(st.sampled_from(NAMES[3:]), max_size=4, unique=True))
    names = draw(st.permutations(["x", "y", "z", *extra]))
    fields, at = [], 0
    for k in names:
        dt = xyz_type if k in "xyz" else draw(st.sampled_from([2, 4, 6, 7]))
        at += draw(st.sampled_from([0, 0, 1, 4]))
        fields.append(point_field(k, at, dt))
        at += SIZES[dt]
    point_step = at + draw(st.sampled_from([0, 0, 3, 8]))
    height, width = draw(st.integers(0, 4)), draw(st.integers(0, 6))
    row_step = width * point_step + draw(st.sampled_from([0, 0, 5]))
    size = (height - 1) * row_step + width * point_step if height and width else 0
    broken = draw(st.sampled_from(["none", "none", "field", "offset", "count", "step", "row", "short", "drop"]))
    f = draw(st.sampled_from(fields))
    if broken == "field":
        f.datatype = draw(st.sampled_from([0, 1, 3, 5, 9, 200]))
    elif broken == "offset":
        f.offset = point_step - draw(st.integers(0, 3))
    elif broken == "count":
        f.count = draw(st.sampled_from([0, 2, 3]))
    elif broken == "step":
        point_step = draw(st.integers(0, max(0, point_step - 1)))
    elif broken == "row":
        row_step = draw(st.integers(0, max(0, width * point_step - 1)))
    elif broken == "short":
        size = max(0, size - draw(st.integers(1, 9)))
    elif broken == "drop":
        fields.remove(f)
    data = np.frombuffer(draw(st.binary(min_size=size, max_size=size)), np.uint8)
    return ros_class(CLOUD)(
        header=header(), height=height, width=width, fields=fields, is_bigendian=draw(st.booleans()),
        point_step=point_step, row_step=row_step, data=data, is_dense=draw(st.booleans()),
    )  # fmt: skip


def _reference_points(msg: object) -> np.ndarray:
    """x, y, z of every point read one by one with struct (the slow, obvious way), finite ones only."""
    f = {p.name: p for p in msg.fields}
    fmt = (">" if msg.is_bigendian else "<") + FORMATS[f["x"].datatype]
    raw = bytes(msg.data)
    out = []
    for r in range(msg.height):
        for c in range(msg.width):
            base = r * msg.row_step + c * msg.point_step
            p = [struct.unpack_from(fmt, raw, base + f[k].offset)[0] for k in "xyz"]
            if all(np.isfinite(p)):
                out.append(p)
    return np.array(out, dtype=np.float32 if f["x"].datatype == 7 else np.float64).reshape(-1, 3)


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(clouds())
def test_a_cloud_converts_exactly_or_is_refused_naming_the_topic(msg):
    try:
        pc = from_ros(CLOUD, msg, topic="/fuzz")
    except ConversionError as exc:
        assert str(exc).startswith("/fuzz: "), exc
        return
    n = msg.height * msg.width
    if n:
        np.testing.assert_array_equal(pc.points, _reference_points(msg))
    else:
        assert pc.points.shape == (0, 3)


@settings(max_examples=150, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(clouds(), st.data())
def test_cut_or_corrupted_cdr_is_refused_naming_the_topic(msg, data):
    cdr = bytearray(typestore().serialize_cdr(msg, CLOUD))
    if data.draw(st.booleans()):
        del cdr[data.draw(st.integers(0, len(cdr))) :]
    else:
        i = data.draw(st.integers(4, len(cdr) - 1))
        cdr[i] = data.draw(st.integers(0, 255))
    try:
        decode(CLOUD, bytes(cdr), topic="/fuzz")
    except ConversionError as exc:
        assert str(exc).startswith("/fuzz: "), exc
