"""``sensor_msgs/PointCloud2`` <-> vgr :class:`~engine.messages.PointCloud`, with numpy views.

ROS -> vgr (:func:`cloud_from_ros`):

* any ``point_step`` (padding between and after fields), row padding (``row_step`` above
  ``width * point_step``), ``is_bigendian`` true or false, organised (``height`` > 1) or not;
* ``x``, ``y``, ``z`` (FLOAT32 or FLOAT64, all three the same) -> ``points`` of that dtype;
  ``normal_x/y/z`` -> ``normals``; colour from a packed ``rgb`` / ``rgba`` field (FLOAT32 or
  UINT32, PCL's layout: ``0x00RRGGBB`` as a uint32 in the cloud's byte order) or from separate UINT8
  ``r``, ``g``, ``b`` (or ``red``, ``green``, ``blue``) -> ``colors``;
* every other field (``intensity``, ``ring``, ``t``, ...) is dropped with a note (vgr's PointCloud
  has no per-point scalar); a cloud without x, y or z is refused;
* vgr's PointCloud is unorganised: an organised cloud is flattened row by row, and **points whose
  x, y or z is not finite are dropped** (whatever ``is_dense`` says: drivers set it wrongly), with
  a note saying how many. Normals and colours of the dropped points go with them;
* cost: the fields are read through strided numpy views of the message's data; the only copy is the
  one that makes ``points`` contiguous, native-endian and free of invalid points (none at all for a
  little-endian, unpadded, all-finite xyz cloud, whose points are a view of the data). Adjacent
  x, y, z move as one 12- (or 24-) byte record per point, byte-swapped in place in that copy.

vgr -> ROS (:func:`cloud_to_ros`): one row (``height`` 1), little-endian, fields ``x, y, z``
(+ ``normal_x, normal_y, normal_z``) in the points' dtype (+ ``rgb`` FLOAT32, PCL packed, alpha
byte 255), no padding; ``is_dense`` true when every point is finite.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.messages import PointCloud
from plugins.ros2.convert_common import Ctx, ros_class, stamp_ns

# sensor_msgs/PointField datatypes
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
_DTYPES: dict[int, np.dtype] = {
    INT8: np.dtype("i1"),
    UINT8: np.dtype("u1"),
    INT16: np.dtype("i2"),
    UINT16: np.dtype("u2"),
    INT32: np.dtype("i4"),
    UINT32: np.dtype("u4"),
    FLOAT32: np.dtype("f4"),
    FLOAT64: np.dtype("f8"),
}
_FLOATS = {FLOAT32: "FLOAT32", FLOAT64: "FLOAT64"}
_XYZ = ("x", "y", "z")
_NORMALS = ("normal_x", "normal_y", "normal_z")
_RGB_FIELDS = (("r", "g", "b"), ("red", "green", "blue"))
_PACKED = ("rgb", "rgba")


class _Layout:
    """The checked geometry of a PointCloud2: counts, steps, the byte buffer, the fields by name."""

    def __init__(self, msg: Any, cx: Ctx) -> None:
        self.cx = cx
        self.height, self.width = int(msg.height), int(msg.width)
        self.n = self.height * self.width
        self.point_step, self.row_step = int(msg.point_step), int(msg.row_step)
        self.big = bool(msg.is_bigendian)
        self.fields: dict[str, Any] = {}
        for f in msg.fields:
            self.fields.setdefault(str(f.name), f)
        data = msg.data if isinstance(msg.data, np.ndarray) else np.frombuffer(msg.data, dtype=np.uint8)
        self.buf = data.reshape(-1)
        if self.n == 0:
            return
        if self.point_step <= 0:
            raise cx.error("point_step", f"is {self.point_step} for {self.n} points")
        if self.row_step < self.width * self.point_step:
            if self.height == 1 and self.row_step == 0:  # (some writers leave row_step unset for one row)
                self.row_step = self.width * self.point_step
            else:
                raise cx.error(
                    "row_step", f"is {self.row_step}, below width x point_step = {self.width * self.point_step}"
                )
        need = (self.height - 1) * self.row_step + self.width * self.point_step
        if self.buf.size < need:
            raise cx.error(
                "data", f"holds {self.buf.size} bytes, {self.height} rows of {self.width} points need {need}: truncated"
            )

    def dtype_of(self, name: str) -> np.dtype:
        """The dtype (in the cloud's byte order) of field *name*, checked against ``point_step``."""
        f = self.fields[name]
        dt = _DTYPES.get(int(f.datatype))
        if dt is None:
            raise self.cx.error(f"fields[{name}].datatype", f"{f.datatype} is no PointField datatype (1..8)")
        if int(f.count) not in (0, 1) and name not in _PACKED:
            raise self.cx.error(f"fields[{name}].count", f"is {f.count}; vgr reads one value per point")
        if int(f.offset) + dt.itemsize > self.point_step:
            raise self.cx.error(
                f"fields[{name}].offset",
                f"{f.offset} + {dt.itemsize} bytes lies beyond point_step {self.point_step}",
            )
        return dt.newbyteorder(">" if self.big else "<")

    def view(self, name: str, dtype: np.dtype, extra: int = 0) -> np.ndarray:
        """(height, width) strided view of field *name* read as *dtype* (at its offset + *extra*)."""
        offset = int(self.fields[name].offset) + extra
        return np.ndarray((self.height, self.width), dtype, self.buf, offset, (self.row_step, self.point_step))

    def triple(self, names: tuple[str, str, str], dtype: np.dtype) -> np.ndarray | None:
        """(height, width, 3) view of three fields of *dtype* when they are adjacent (else None)."""
        offsets = [int(self.fields[k].offset) for k in names]
        if offsets[1] - offsets[0] != dtype.itemsize or offsets[2] - offsets[1] != dtype.itemsize:
            return None
        return np.ndarray(
            (self.height, self.width, 3), dtype, self.buf, offsets[0], (self.row_step, self.point_step, dtype.itemsize)
        )

    def gather(self, names: tuple[str, str, str], dtype: np.dtype, keep: np.ndarray | None) -> np.ndarray:
        """The fields *names* (read as *dtype*) of the points *keep* (None: all) as a C-contiguous
        (k, 3) array in native byte order: a view of the data when it is that already, else one copy.
        Adjacent fields move as one opaque record per point (numpy's boolean indexing of records is
        3-4x faster than of strided rows), byte-swapped in place in vgr's own copy."""
        native = dtype.newbyteorder("=")
        size = dtype.itemsize
        trio = self.triple(names, dtype)
        if trio is None:  # fields apart or out of order: column by column
            out = np.empty((self.n if keep is None else int(keep.sum()), 3), native)
            for i, k in enumerate(names):
                col = self.view(k, dtype)
                out[:, i] = col.reshape(-1) if keep is None else col[keep.reshape(col.shape)]
            return out
        flat = self.height == 1 or self.row_step == self.width * self.point_step
        if keep is None and flat and self.point_step == 3 * size and dtype == native:
            return trio.reshape(self.n, 3)  # (a view: nothing to copy)
        offset = int(self.fields[names[0]].offset)
        rec = np.ndarray(
            (self.height, self.width), np.dtype((np.void, 3 * size)), self.buf, offset, (self.row_step, self.point_step)
        )
        moved = rec.copy() if keep is None else rec[keep.reshape(rec.shape)]
        out = moved.reshape(-1).view(dtype).reshape(-1, 3)
        if dtype != native:
            out.byteswap(inplace=True)
            out = out.view(native)
        return out

    def channels(self, views: list[np.ndarray], keep: np.ndarray | None) -> np.ndarray:
        """(k, 3) uint8 of three (height, width) byte views, the points *keep* only."""
        rgb = np.empty((self.n if keep is None else int(keep.sum()), 3), np.uint8)
        for i, ch in enumerate(views):
            rgb[:, i] = ch.reshape(-1) if keep is None else ch[keep.reshape(ch.shape)]
        return rgb


def cloud_from_ros(msg: Any, cx: Ctx) -> PointCloud:
    lay = _Layout(msg, cx)
    missing = [k for k in _XYZ if k not in lay.fields]
    if missing:
        have = ", ".join(lay.fields) or "none"
        raise cx.error("fields", f"no {', '.join(missing)} field (fields: {have}): not a cloud of points")
    frame = cx.to_vgr(str(msg.header.frame_id))
    stamp = stamp_ns(msg.header.stamp)
    if lay.n == 0:
        return PointCloud(stamp_ns=stamp, frame_id=frame, points=np.zeros((0, 3), np.float32))
    xyz_types = {k: int(lay.fields[k].datatype) for k in _XYZ}
    for k, t in xyz_types.items():
        if t not in _FLOATS:
            raise cx.error(f"fields[{k}].datatype", f"is {t}; vgr reads x, y, z as FLOAT32 (7) or FLOAT64 (8)")
    if len(set(xyz_types.values())) > 1:
        raise cx.error("fields", f"x, y, z have different datatypes {list(xyz_types.values())}")
    dt = lay.dtype_of("x")
    for k in _XYZ[1:]:
        lay.dtype_of(k)
    trio = lay.triple(_XYZ, dt)
    fin = np.isfinite(trio if trio is not None else np.stack([lay.view(k, dt) for k in _XYZ], axis=-1))
    keep: np.ndarray | None = None  # (a per-row .all(axis=1) over fin would cost 8x the whole conversion)
    if not fin.all():
        keep = (fin[..., 0] & fin[..., 1] & fin[..., 2]).reshape(-1)
        cx.note(f"{int(lay.n - keep.sum())} of {lay.n} points with a non-finite x, y or z dropped")
    points = lay.gather(_XYZ, dt, keep)
    normals = _normals(lay, keep, points.dtype)
    colors = _colors(lay, keep)
    dropped = sorted(set(lay.fields) - set(_XYZ) - _used_extra(lay))
    if dropped:
        cx.note(f"field(s) {', '.join(dropped)} dropped (vgr's PointCloud has points, normals and colours only)")
    return PointCloud(stamp_ns=stamp, frame_id=frame, points=points, normals=normals, colors=colors)


def _used_extra(lay: _Layout) -> set[str]:
    used: set[str] = set()
    if all(k in lay.fields for k in _NORMALS):
        used.update(_NORMALS)
    packed = next((k for k in _PACKED if k in lay.fields), None)
    if packed is not None:
        used.add(packed)
    else:
        names = next((ns for ns in _RGB_FIELDS if all(k in lay.fields for k in ns)), None)
        used.update(names or ())
    return used


def _normals(lay: _Layout, keep: np.ndarray | None, dtype: np.dtype) -> np.ndarray | None:
    if not all(k in lay.fields for k in _NORMALS):
        return None
    types = {int(lay.fields[k].datatype) for k in _NORMALS}
    if len(types) > 1 or not types <= set(_FLOATS):
        problem = f"normals must be FLOAT32 or FLOAT64 alike, got {sorted(types)}"
        raise lay.cx.error("fields[normal_x].datatype", problem)
    ndt = lay.dtype_of("normal_x")
    for k in _NORMALS[1:]:
        lay.dtype_of(k)
    normals = lay.gather(_NORMALS, ndt, keep)
    return normals if normals.dtype == dtype else normals.astype(dtype)


def _colors(lay: _Layout, keep: np.ndarray | None) -> np.ndarray | None:
    packed = next((k for k in _PACKED if k in lay.fields), None)
    if packed is not None:
        lay.dtype_of(packed)
        if int(lay.fields[packed].datatype) not in (FLOAT32, UINT32):
            raise lay.cx.error(f"fields[{packed}].datatype", f"is {lay.fields[packed].datatype}: FLOAT32 or UINT32")
        # the packed value is 0x(AA)RRGGBB as a uint32 in the cloud's byte order
        order = (1, 2, 3) if lay.big else (2, 1, 0)
        return lay.channels([lay.view(packed, np.dtype("u1"), extra=o) for o in order], keep)
    names = next((ns for ns in _RGB_FIELDS if all(k in lay.fields for k in ns)), None)
    if names is None:
        return None
    for k in names:
        if int(lay.fields[k].datatype) != UINT8:
            raise lay.cx.error(f"fields[{k}].datatype", f"is {lay.fields[k].datatype}; separate colours are UINT8 (2)")
        lay.dtype_of(k)
    return lay.gather(names, np.dtype("u1"), keep)


def cloud_to_ros(m: PointCloud, cx: Ctx) -> Any:
    PointField = ros_class("sensor_msgs/msg/PointField")
    pts = np.asarray(m.points)
    n = len(pts)
    ftype = FLOAT64 if pts.dtype == np.float64 else FLOAT32
    size = pts.dtype.itemsize
    cols: list[tuple[str, np.ndarray, np.dtype]] = [(k, pts[:, i], pts.dtype) for i, k in enumerate(_XYZ)]
    fields = [PointField(name=k, offset=i * size, datatype=ftype, count=1) for i, k in enumerate(_XYZ)]
    offset = 3 * size
    if m.normals is not None:
        for i, k in enumerate(_NORMALS):
            fields.append(PointField(name=k, offset=offset, datatype=ftype, count=1))
            cols.append((k, np.asarray(m.normals)[:, i], pts.dtype))
            offset += size
    if m.colors is not None:
        c = np.asarray(m.colors, dtype=np.uint32)
        packed = (np.uint32(255) << 24) | (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
        fields.append(PointField(name="rgb", offset=offset, datatype=FLOAT32, count=1))
        cols.append(("rgb", packed.view(np.float32), np.dtype("<f4")))
        offset += 4
    if len(cols) == 3:
        data = np.ascontiguousarray(pts).astype(pts.dtype.newbyteorder("<"), copy=False).reshape(-1).view(np.uint8)
    else:
        rec = np.empty(n, dtype=np.dtype([(k, dt.newbyteorder("<")) for k, _, dt in cols]))
        for k, a, _ in cols:
            rec[k] = a
        data = rec.view(np.uint8).reshape(-1)
    return ros_class("sensor_msgs/msg/PointCloud2")(
        header=cx.header(m.stamp_ns, m.frame_id),
        height=1,
        width=n,
        fields=fields,
        is_bigendian=False,
        point_step=offset,
        row_step=offset * n,
        data=data,
        is_dense=bool(np.isfinite(pts).all()),
    )
