"""Types marked WIRE_EXACT are handed to local consumers as objects: their protobuf round trip must
reproduce them bit for bit, or a local consumer would see something a replay does not."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from engine.messages import Blob, Image, PointCloud, PoseStamped, Request, canonical

floats = st.floats(allow_nan=False, allow_infinity=False, width=64)


def same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    return a == b


def roundtrip_equal(msg) -> bool:
    pb, bulk = msg.to_proto()
    back = type(msg).from_proto(pb, bulk)
    return all(same(v, getattr(back, k)) for k, v in msg.__dict__.items() if k not in ("seq", "_wire"))


@settings(max_examples=30, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(0, 50), st.just(3)), elements=st.floats(-10, 10, width=32)))
def test_point_cloud_float32_is_wire_exact(points):
    assert PointCloud.WIRE_EXACT and roundtrip_equal(PointCloud(points=points, frame_id="camera", stamp_ns=7))


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(0, 50), st.just(3)), elements=floats))
def test_point_cloud_float64_is_wire_exact(points):
    assert roundtrip_equal(PointCloud(points=points, frame_id="camera", stamp_ns=7))


@settings(max_examples=30, deadline=None)
@given(
    st.dictionaries(st.text(min_size=1, max_size=5), st.one_of(floats, st.integers(-1000, 1000), st.text(max_size=5)))
)
def test_request_is_wire_exact(args):
    assert Request.WIRE_EXACT and roundtrip_equal(Request(command="go", args=args, stamp_ns=3))


def test_image_and_blob_are_wire_exact():
    img = Image(data=np.random.default_rng(0).random((4, 5)).astype(np.float32), encoding="32FC1", frame_id="c")
    assert Image.WIRE_EXACT and roundtrip_equal(img)
    assert Blob.WIRE_EXACT and roundtrip_equal(Blob(data=b"\x00\x01abc", frame_id="x"))


def test_a_pose_is_handed_over_with_the_bytes_it_came_from():
    """Quaternion -> matrix -> quaternion is not always a fixed point: the canonical message keeps
    the protobuf it was rebuilt from, so its recorded bytes decode to exactly what was handed over."""
    from scipy.spatial.transform import Rotation

    from engine.messages import codec

    rng = np.random.default_rng(1)
    for _ in range(50):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.normal(size=3)
        wire = canonical(PoseStamped(T=T, frame_id="base", stamp_ns=5))
        back = codec.decode_payload(PoseStamped, codec.encode_payload(wire))
        assert back.T.tobytes() == wire.T.tobytes()
        assert np.allclose(wire.T, T, atol=1e-12)
