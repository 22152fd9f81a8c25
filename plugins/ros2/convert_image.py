"""``sensor_msgs/Image`` <-> vgr :class:`~engine.messages.Image`, ``sensor_msgs/CameraInfo`` <->
vgr :class:`~engine.messages.CameraInfo`.

Image: the encodings vgr knows, ``32FC1`` (depth in metres), ``64FC1``, ``16UC1`` (``mono16`` is
read as ``16UC1``, with a note), ``mono8``, ``rgb8``, ``bgr8``; any other is refused, naming
``encoding``. Rows may be padded (``step`` above ``width`` x pixel size) and multi-byte pixels
big-endian (``is_bigendian``): the pixels are then copied once into a contiguous native array,
otherwise they are a view of the message's data. vgr -> ROS: unpadded rows, little-endian.

CameraInfo: ``k`` -> ``K`` (3x3), ``d`` -> ``D``, ``distortion_model``, ``width``, ``height``. Dropped
(vgr's camera model is unrectified): ``r``, ``p``, ``binning_x/y``, ``roi``; vgr -> ROS writes
``r`` = identity and ``p`` = [K | 0], as for an unrectified camera (and as vgr's Foxglove schema does).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.messages import CameraInfo, Image
from plugins.ros2.convert_common import Ctx, ros_class, stamp_ns

ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    "32FC1": (np.dtype("f4"), 1),
    "64FC1": (np.dtype("f8"), 1),
    "16UC1": (np.dtype("u2"), 1),
    "mono8": (np.dtype("u1"), 1),
    "rgb8": (np.dtype("u1"), 3),
    "bgr8": (np.dtype("u1"), 3),
}
ALIASES = {"mono16": "16UC1"}  # same pixels, a name vgr's Image does not have


def image_from_ros(msg: Any, cx: Ctx) -> Image:
    encoding = str(msg.encoding)
    if encoding in ALIASES:
        cx.note(f"encoding {encoding} read as {ALIASES[encoding]}")
        encoding = ALIASES[encoding]
    if encoding not in ENCODINGS:
        raise cx.error("encoding", f"{msg.encoding!r} is not one vgr reads ({', '.join(ENCODINGS)})")
    dt, ch = ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * ch * dt.itemsize
    if h and w and step < row:
        raise cx.error("step", f"is {step}, below width x pixel size = {row}")
    buf = msg.data if isinstance(msg.data, np.ndarray) else np.frombuffer(msg.data, np.uint8)
    buf = buf.reshape(-1)
    need = (h - 1) * step + row if h and w else 0
    if buf.size < need:
        raise cx.error("data", f"holds {buf.size} bytes, {h} rows of {step} need {need}: truncated")
    wire = dt.newbyteorder(">" if msg.is_bigendian else "<")
    shape = (h, w) if ch == 1 else (h, w, ch)
    strides = (step, ch * dt.itemsize) if ch == 1 else (step, ch * dt.itemsize, dt.itemsize)
    data = np.ndarray(shape, wire, buf, 0, strides) if need else np.zeros(shape, dt)
    if data.dtype != dt.newbyteorder("="):
        data = data.astype(dt.newbyteorder("="))  # the one copy: byte order (and padding) fixed
    elif not data.flags.c_contiguous:
        data = np.ascontiguousarray(data)
    return Image(stamp_ns=stamp_ns(msg.header.stamp), frame_id=cx.to_vgr(str(msg.header.frame_id)), data=data,
                 encoding=encoding)  # fmt: skip


def image_to_ros(m: Image, cx: Ctx) -> Any:
    dt, ch = ENCODINGS[m.encoding]
    data = np.ascontiguousarray(m.data, dtype=dt.newbyteorder("<"))
    h, w = data.shape[:2]
    return ros_class("sensor_msgs/msg/Image")(
        header=cx.header(m.stamp_ns, m.frame_id),
        height=h,
        width=w,
        encoding=m.encoding,
        is_bigendian=0,
        step=w * ch * dt.itemsize,
        data=data.reshape(-1).view(np.uint8),
    )


def camera_info_from_ros(msg: Any, cx: Ctx) -> CameraInfo:
    k = np.asarray(msg.k, dtype=float)
    if k.size != 9:
        raise cx.error("k", f"has {k.size} values, not 9")
    return CameraInfo(
        stamp_ns=stamp_ns(msg.header.stamp),
        frame_id=cx.to_vgr(str(msg.header.frame_id)),
        width=int(msg.width),
        height=int(msg.height),
        K=k.reshape(3, 3).copy(),
        D=np.asarray(msg.d, dtype=float).copy(),
        distortion_model=str(msg.distortion_model),
    )


def camera_info_to_ros(m: CameraInfo, cx: Ctx) -> Any:
    K = np.asarray(m.K, dtype=float).reshape(3, 3)
    P = np.zeros((3, 4))
    P[:, :3] = K
    roi = ros_class("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return ros_class("sensor_msgs/msg/CameraInfo")(
        header=cx.header(m.stamp_ns, m.frame_id),
        height=int(m.height),
        width=int(m.width),
        distortion_model=m.distortion_model,
        d=np.asarray(m.D, dtype=np.float64).reshape(-1).copy(),
        k=K.reshape(-1).copy(),
        r=np.eye(3).reshape(-1),
        p=P.reshape(-1),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
