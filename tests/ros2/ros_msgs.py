"""Test helpers: ROS 2 messages built by hand (typestore dataclasses), as a driver would send them."""

from __future__ import annotations

from typing import Any

import numpy as np

from plugins.ros2.convert_common import ros_class

FLOAT = {np.dtype("f4"): 7, np.dtype("f8"): 8, np.dtype("u1"): 2, np.dtype("u4"): 6, np.dtype("u2"): 4}


def header(sec: int = 1_700_000_000, nanosec: int = 123_456_789, frame: str = "camera_optical") -> Any:
    return ros_class("std_msgs/msg/Header")(stamp=ros_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec),
                                            frame_id=frame)  # fmt: skip


def point_field(name: str, offset: int, datatype: int, count: int = 1) -> Any:
    return ros_class("sensor_msgs/msg/PointField")(name=name, offset=offset, datatype=datatype, count=count)


def cloud2(
    columns: dict[str, np.ndarray],
    *,
    offsets: dict[str, int] | None = None,
    point_step: int | None = None,
    big: bool = False,
    height: int = 1,
    row_pad: int = 0,
    frame: str = "camera_optical",
) -> Any:
    """A PointCloud2 of *columns* (name -> (N,) array), each at its offset (default packed in order),
    points *point_step* apart, *height* rows with *row_pad* bytes after each, in the byte order asked."""
    names = list(columns)
    n = len(next(iter(columns.values())))
    if offsets is None:
        offsets, at = {}, 0
        for k in names:
            offsets[k] = at
            at += columns[k].dtype.itemsize
    step = point_step or max(offsets[k] + columns[k].dtype.itemsize for k in names)
    order = ">" if big else "<"
    dt = np.dtype(
        {
            "names": names,
            "formats": [columns[k].dtype.newbyteorder(order) for k in names],
            "offsets": [offsets[k] for k in names],
            "itemsize": step,
        }
    )
    rec = np.zeros(n, dt)
    for k in names:
        rec[k] = columns[k]
    width = n // height
    rows = rec.view(np.uint8).reshape(height, width * step)
    data = np.concatenate([rows, np.full((height, row_pad), 0xAB, np.uint8)], axis=1).reshape(-1)
    return ros_class("sensor_msgs/msg/PointCloud2")(
        header=header(frame=frame),
        height=height,
        width=width,
        fields=[point_field(k, offsets[k], FLOAT[columns[k].dtype.newbyteorder("=")]) for k in names],
        is_bigendian=big,
        point_step=step,
        row_step=width * step + row_pad,
        data=data,
        is_dense=False,
    )


def image(data: np.ndarray, encoding: str, *, big: bool = False, row_pad: int = 0) -> Any:
    h, w = data.shape[:2]
    raw = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder(">" if big else "<")).reshape(h, -1).view(np.uint8)
    rows = np.concatenate([raw, np.zeros((h, row_pad), np.uint8)], axis=1)
    return ros_class("sensor_msgs/msg/Image")(
        header=header(), height=h, width=w, encoding=encoding, is_bigendian=int(big), step=rows.shape[1],
        data=rows.reshape(-1),
    )  # fmt: skip
