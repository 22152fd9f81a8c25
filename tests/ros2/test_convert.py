"""plugins.ros2.convert: every conversion both ways, the cloud and image layouts drivers send, the
errors (naming topic and field), exact time stamps, frame mappings and the cost of a large cloud."""

from __future__ import annotations

import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from ros_msgs import cloud2, header, image

from engine import transforms as tf
from engine.messages import (
    CameraInfo,
    FrameTransforms,
    Image,
    JointState,
    PointCloud,
    PoseStamped,
    PoseWithCovarianceStamped,
    Transform,
    codec,
)
from plugins.ros2.convert import (
    SUPPORTED,
    ConversionError,
    FrameMap,
    decode,
    encode,
    from_ros,
    ros_type_of,
    to_ros,
)
from plugins.ros2.convert_common import ros_class, typestore

ROOT = Path(__file__).resolve().parents[2]
CLOUD = "sensor_msgs/msg/PointCloud2"
RNG = np.random.default_rng(7)


def _T(seed: int) -> np.ndarray:
    r = np.random.default_rng(seed)
    q = r.normal(size=4)
    return tf.T_from_pose7(r.normal(size=3), q / np.linalg.norm(q))


def _samples() -> list[object]:
    pts = RNG.normal(size=(50, 3)).astype(np.float32)
    return [
        PointCloud(stamp_ns=1_700_000_000_000_000_001, frame_id="camera", points=pts),
        PointCloud(stamp_ns=2, frame_id="camera", points=pts.astype(np.float64), normals=-pts.astype(np.float64)),
        PointCloud(stamp_ns=3, frame_id="camera", points=pts, colors=RNG.integers(0, 256, (50, 3), dtype=np.uint8)),
        Image(stamp_ns=4, frame_id="camera", data=RNG.random((6, 7)).astype(np.float32), encoding="32FC1"),
        Image(stamp_ns=5, frame_id="camera", data=RNG.integers(0, 256, (6, 7, 3), dtype=np.uint8), encoding="bgr8"),
        Image(stamp_ns=6, frame_id="camera", data=RNG.integers(0, 65535, (6, 7), dtype=np.uint16), encoding="16UC1"),
        CameraInfo(
            stamp_ns=7,
            frame_id="camera",
            width=640,
            height=480,
            K=np.array([[600.0, 0, 320.5], [0, 601.0, 240.25], [0, 0, 1]]),
            D=np.array([0.1, -0.2, 0, 0, 0.01]),
        ),
        JointState(
            stamp_ns=8, names=[f"j{i}" for i in range(6)], positions=RNG.normal(size=6), velocities=RNG.normal(size=6)
        ),
        JointState(stamp_ns=9, names=["a", "b"], positions=np.array([0.5, -0.25]), efforts=np.array([1.0, 2.0])),
        PoseStamped(stamp_ns=10, frame_id="base", T=_T(1)),
        PoseWithCovarianceStamped(stamp_ns=11, frame_id="base", T=_T(2), covariance=np.diag(np.arange(1.0, 7.0))),
        Transform(stamp_ns=12, frame_id="world", child_frame_id="base", T=_T(3)),
        FrameTransforms(
            stamp_ns=13,
            transforms=[
                Transform(stamp_ns=13, frame_id="world", child_frame_id="base", T=_T(4)),
                Transform(stamp_ns=13, frame_id="base", child_frame_id="tcp", T=_T(5)),
            ],
        ),
    ]


@pytest.mark.parametrize("msg", _samples(), ids=lambda m: type(m).__name__)
def test_vgr_to_ros_and_back_is_bit_exact(msg):
    msgtype = ros_type_of(type(msg))
    back = decode(msgtype, encode(msg, msgtype), topic="/t")
    assert type(back) is type(msg)
    assert codec.encode_payload(back) == codec.encode_payload(msg)


@pytest.mark.parametrize("msg", _samples(), ids=lambda m: type(m).__name__)
def test_ros_to_vgr_and_back_gives_the_same_cdr(msg):
    """A ROS message (as vgr sends it) crosses vgr and comes back as the same bytes: poses keep their
    quaternion to the bit (vgr carries it), not only the 4x4."""
    msgtype = ros_type_of(type(msg))
    cdr = encode(msg, msgtype)
    again = encode(decode(msgtype, cdr, topic="/t"), msgtype)
    assert again == cdr


def test_a_quaternion_not_of_vgrs_making_crosses_bit_exactly():
    q = np.array([0.1, 0.2, 0.3, 0.9])
    q = -(q / np.linalg.norm(q))  # w < 0: vgr would write the other sign
    ros = ros_class("geometry_msgs/msg/PoseStamped")(
        header=header(frame="base_link"),
        pose=ros_class("geometry_msgs/msg/Pose")(
            position=ros_class("geometry_msgs/msg/Point")(x=0.1, y=0.2, z=0.3),
            orientation=ros_class("geometry_msgs/msg/Quaternion")(x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )
    cdr = bytes(typestore().serialize_cdr(ros, "geometry_msgs/msg/PoseStamped"))
    m = decode("geometry_msgs/msg/PoseStamped", cdr, topic="/pose")
    np.testing.assert_allclose(m.T, tf.T_from_pose7([0.1, 0.2, 0.3], q), atol=1e-15)
    replayed = codec.decode_payload(PoseStamped, codec.encode_payload(m))
    replayed.__dict__["_wire"] = (PoseStamped.proto().FromString(codec.encode_payload(m)), None)
    assert encode(replayed, "geometry_msgs/msg/PoseStamped") == cdr


def test_supported_types_are_jazzy_definitions_and_equal_in_humble_and_kilted():
    from rosbags.typesys import Stores, get_typestore

    jazzy = typestore()
    names = set(SUPPORTED) | {"std_msgs/msg/Header", "builtin_interfaces/msg/Time", "sensor_msgs/msg/PointField"}
    for other in (Stores.ROS2_HUMBLE, Stores.ROS2_KILTED):
        store = get_typestore(other)
        for name in names:
            assert store.fielddefs[name] == jazzy.fielddefs[name], (other, name)


# --------------------------------------------------------------------------- clouds


def _xyz(n: int, dtype: str = "f4") -> dict[str, np.ndarray]:
    p = RNG.normal(size=(n, 3)).astype(dtype)
    return {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}


def _points(cols: dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([cols["x"], cols["y"], cols["z"]], axis=1)


@pytest.mark.parametrize("big", [False, True])
@pytest.mark.parametrize("dtype", ["f4", "f8"])
def test_organised_padded_cloud_in_either_byte_order(big, dtype):
    cols = _xyz(24, dtype)
    msg = cloud2(cols, point_step=32 if dtype == "f8" else 16, big=big, height=4, row_pad=5)
    pc = from_ros(CLOUD, msg, topic="/cam/points")
    assert pc.points.dtype == np.dtype(dtype) and pc.points.flags.c_contiguous
    np.testing.assert_array_equal(pc.points, _points(cols))
    assert (pc.stamp_ns, pc.frame_id) == (1_700_000_000_123_456_789, "camera_optical")


def test_fields_in_any_order_and_unknown_ones_dropped_with_a_note():
    cols = _xyz(10)
    cols = {"intensity": RNG.random(10).astype("f4"), "z": cols["z"], "ring": np.arange(10, dtype="u2"),
            "x": cols["x"], "y": cols["y"]}  # fmt: skip
    notes: list[str] = []
    pc = from_ros(CLOUD, cloud2(cols, point_step=24), topic="/lidar", notes=notes)
    np.testing.assert_array_equal(pc.points, _points(cols))
    assert pc.colors is None and pc.normals is None
    assert any("intensity" in n and "ring" in n for n in notes), notes


@pytest.mark.parametrize("big", [False, True])
@pytest.mark.parametrize("kind", ["f4", "u4"])
def test_packed_rgb_float_or_uint(big, kind):
    cols = _xyz(12)
    rgb = RNG.integers(0, 256, (12, 3), dtype=np.uint32)
    packed = (np.uint32(255) << 24) | (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    cols["rgb"] = packed.view(np.float32) if kind == "f4" else packed
    pc = from_ros(CLOUD, cloud2(cols, point_step=32, big=big), topic="/rgbd")
    np.testing.assert_array_equal(pc.colors, rgb.astype(np.uint8))


def test_separate_rgb_bytes_and_normals():
    cols = _xyz(9)
    c = RNG.integers(0, 256, (9, 3), dtype=np.uint8)
    n = RNG.normal(size=(9, 3)).astype("f4")
    cols |= {"normal_x": n[:, 0], "normal_y": n[:, 1], "normal_z": n[:, 2], "r": c[:, 0], "g": c[:, 1], "b": c[:, 2]}
    pc = from_ros(CLOUD, cloud2(cols, point_step=40), topic="/c")
    np.testing.assert_array_equal(pc.colors, c)
    np.testing.assert_array_equal(pc.normals, n)


def test_non_finite_points_are_dropped_with_their_colours_and_a_note():
    cols = _xyz(20)
    cols["z"][[3, 7]] = np.nan
    cols["x"][11] = np.inf
    c = RNG.integers(0, 256, (20, 3), dtype=np.uint8)
    cols |= {"r": c[:, 0], "g": c[:, 1], "b": c[:, 2]}
    notes: list[str] = []
    pc = from_ros(CLOUD, cloud2(cols, height=2), topic="/c", notes=notes)
    keep = np.ones(20, bool)
    keep[[3, 7, 11]] = False
    np.testing.assert_array_equal(pc.points, _points(cols)[keep])
    np.testing.assert_array_equal(pc.colors, c[keep])
    assert any("3 of 20 points" in n for n in notes), notes


def test_an_empty_cloud():
    pc = from_ros(CLOUD, cloud2(_xyz(0)), topic="/c")
    assert pc.points.shape == (0, 3)


def test_a_large_padded_cloud_decodes_with_one_copy_of_its_points():
    """100k points, xyz float32 padded to 16 bytes (1.6 MB of data): the decode allocates the
    contiguous points (1.2 MB) and small masks, never a second copy of the data (tracemalloc sees
    numpy's allocations)."""
    cols = _xyz(100_000)
    cdr = bytes(typestore().serialize_cdr(cloud2(cols, point_step=16), CLOUD))
    decode(CLOUD, cdr, topic="/c")  # (first use: the typestore's generated code)
    tracemalloc.start()
    try:
        pc = decode(CLOUD, cdr, topic="/c")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert pc.points.nbytes == 1_200_000
    assert peak < 1_200_000 + 600_000, peak  # points + the finiteness mask (0.4 MB), not the 1.6 MB data again
    np.testing.assert_array_equal(pc.points, _points(cols))


def test_an_unpadded_little_endian_cloud_is_a_view_of_the_message():
    msg = cloud2(_xyz(100))
    pc = from_ros(CLOUD, msg, topic="/c")
    assert np.shares_memory(pc.points, msg.data)


# --------------------------------------------------------------------------- errors


def _error(msgtype: str, msg: object, topic: str = "/cam/points", **kw: object) -> ConversionError:
    with pytest.raises(ConversionError) as info:
        from_ros(msgtype, msg, topic=topic, **kw)
    assert topic in str(info.value)
    return info.value


def test_a_cloud_without_z_names_the_fields():
    cols = _xyz(5)
    del cols["z"]
    err = _error(CLOUD, cloud2(cols))
    assert "fields" in err.field and "z" in str(err)


def test_a_point_step_smaller_than_the_fields():
    msg = cloud2(_xyz(5))
    msg.point_step = 8
    msg.row_step = 40
    err = _error(CLOUD, msg)
    assert "fields[z].offset" in err.field and "point_step 8" in str(err)


def test_a_truncated_data_array():
    msg = cloud2(_xyz(5), height=1)
    msg.data = msg.data[:-3]
    err = _error(CLOUD, msg)
    assert err.field.endswith(".data") and "truncated" in str(err)


def test_truncated_cdr_names_the_topic():
    cdr = encode(PointCloud(points=np.zeros((10, 3), np.float32)), CLOUD)
    with pytest.raises(ConversionError, match="/cam/points"):
        decode(CLOUD, cdr[:-20], topic="/cam/points")


def test_an_unconvertible_type():
    with pytest.raises(ConversionError, match=r"/odom: type: nav_msgs/msg/Odometry has no vgr conversion"):
        decode("nav_msgs/msg/Odometry", b"\x00\x01\x00\x00", topic="/odom")
    with pytest.raises(ConversionError, match="type"):
        encode(PoseStamped(), CLOUD, topic="/x")


def test_integer_xyz_and_a_zero_quaternion_are_refused():
    cols = {k: np.arange(4, dtype="u2") for k in "xyz"}
    assert "datatype" in _error(CLOUD, cloud2(cols)).field
    zero = ros_class("geometry_msgs/msg/PoseStamped")(
        header=header(), pose=ros_class("geometry_msgs/msg/Pose")(
            position=ros_class("geometry_msgs/msg/Point")(x=0.0, y=0.0, z=0.0),
            orientation=ros_class("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.0, w=0.0)))  # fmt: skip
    assert _error("geometry_msgs/msg/PoseStamped", zero, "/pose").field.endswith("pose.orientation")


def test_joint_state_arrays_of_other_lengths():
    js = to_ros(JointState(names=["a", "b"], positions=np.zeros(2)), "sensor_msgs/msg/JointState")
    js.velocity = np.zeros(3)
    assert _error("sensor_msgs/msg/JointState", js, "/joint_states").field.endswith("velocity")


# --------------------------------------------------------------------------- images


@pytest.mark.parametrize("big", [False, True])
@pytest.mark.parametrize(
    ("encoding", "shape", "dtype"),
    [("32FC1", (5, 4), "f4"), ("64FC1", (5, 4), "f8"), ("16UC1", (5, 4), "u2"), ("mono8", (5, 4), "u1"),
     ("rgb8", (5, 4, 3), "u1"), ("bgr8", (5, 4, 3), "u1")],
)  # fmt: skip
def test_images_with_padded_rows_in_either_byte_order(encoding, shape, dtype, big):
    data = (RNG.random(shape) * 200).astype(dtype)
    im = from_ros("sensor_msgs/msg/Image", image(data, encoding, big=big, row_pad=3), topic="/depth")
    assert im.encoding == encoding and im.data.flags.c_contiguous
    np.testing.assert_array_equal(im.data, data)


def test_an_unknown_encoding_and_a_short_step():
    msg = image(np.zeros((2, 2), np.uint8), "yuv422")
    assert _error("sensor_msgs/msg/Image", msg, "/img").field.endswith("encoding")
    msg = image(np.zeros((2, 2), np.float32), "32FC1")
    msg.step = 4
    assert _error("sensor_msgs/msg/Image", msg, "/img").field.endswith("step")


def test_camera_info_keeps_k_d_and_writes_an_unrectified_p():
    ci = _samples()[6]
    ros = to_ros(ci, "sensor_msgs/msg/CameraInfo")
    np.testing.assert_array_equal(ros.p.reshape(3, 4)[:, :3], ci.K)
    np.testing.assert_array_equal(ros.r, np.eye(3).ravel())


# --------------------------------------------------------------------------- time and frames


@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 1_000_000_000, -1, -1_500_000_000, 2**31 * 10**9 - 1])
def test_time_stamps_are_exact(ns):
    ros = to_ros(PoseStamped(stamp_ns=ns), "geometry_msgs/msg/PoseStamped")
    assert 0 <= ros.header.stamp.nanosec < 10**9
    assert ros.header.stamp.sec * 10**9 + ros.header.stamp.nanosec == ns
    assert from_ros("geometry_msgs/msg/PoseStamped", ros, topic="/p").stamp_ns == ns


def test_a_time_beyond_int32_seconds_is_refused():
    with pytest.raises(ConversionError, match=r"header\.stamp"):
        to_ros(PoseStamped(stamp_ns=2**31 * 10**9), "geometry_msgs/msg/PoseStamped", topic="/p")


def test_frames_are_mapped_both_ways_and_a_strict_map_refuses_others():
    frames = {"camera_depth_optical_frame": "camera", "base_link": "base"}
    msg = cloud2(_xyz(3), frame="camera_depth_optical_frame")
    assert from_ros(CLOUD, msg, topic="/c", frames=frames).frame_id == "camera"
    assert from_ros(CLOUD, cloud2(_xyz(3), frame="other"), topic="/c", frames=frames).frame_id == "other"
    err = _error(CLOUD, cloud2(_xyz(3), frame="other"), "/c", frames=FrameMap(frames, strict=True))
    assert err.field.endswith("header.frame_id") and "other" in str(err)
    tfm = FrameTransforms(transforms=[Transform(frame_id="base", child_frame_id="camera", T=np.eye(4))])
    ros = to_ros(tfm, "tf2_msgs/msg/TFMessage", frames=frames)
    t = ros.transforms[0]
    assert (t.header.frame_id, t.child_frame_id) == ("base_link", "camera_depth_optical_frame")
    with pytest.raises(ConversionError, match=r"transforms\[0\].child_frame_id"):
        to_ros(FrameTransforms(transforms=[Transform(frame_id="base", child_frame_id="tool", T=np.eye(4))]),
               "tf2_msgs/msg/TFMessage", frames=FrameMap(frames, strict=True), topic="/tf")  # fmt: skip


# --------------------------------------------------------------------------- without the extra


def test_vgr_imports_the_conversions_without_rosbags_and_says_how_to_get_it():
    code = (
        "import sys; sys.modules['rosbags'] = None\n"
        "import plugins.ros2.convert as c\n"
        "assert 'sensor_msgs/msg/PointCloud2' in c.SUPPORTED\n"
        "try:\n    c.decode('sensor_msgs/msg/JointState', b'', topic='/j')\n"
        "except c.MissingExtraError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})  # fmt: skip
    assert "pip install vgr[ros2]" in out.stdout, out.stderr[-2000:]


def test_big_endian_cdr_decodes_as_little_endian_does():
    for msg in (_samples()[0], _samples()[7], _samples()[12]):
        msgtype = ros_type_of(type(msg))
        cdr = bytes(typestore().serialize_cdr(to_ros(msg, msgtype), msgtype, little_endian=False))
        assert cdr[:2] == b"\x00\x00"  # the encapsulation header says big-endian CDR
        assert codec.encode_payload(decode(msgtype, cdr, topic="/t")) == codec.encode_payload(msg)
