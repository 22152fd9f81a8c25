"""Message types on Foxglove's well-known schemas, so a recording opens in Foxglove's 3D view:
point clouds, images and their camera model, poses, transforms, joint states and scene meshes.

Camera models, poses and transforms map to their schemas by field (engine.messages.mapping); point
clouds, images, joint states and meshes pack their arrays in Foxglove's layouts by hand."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

import numpy as np

from engine.messages.base import Message
from engine.messages.mapping import Bulk, Wire, WireMap, _bytes_of, get_stamp, set_stamp
from engine.messages.schemas import ProtoMessage

_PACKED_TYPES = {  # foxglove.PackedElementField.NumericType
    np.dtype("uint8"): 1,
    np.dtype("int8"): 2,
    np.dtype("uint16"): 3,
    np.dtype("int16"): 4,
    np.dtype("uint32"): 5,
    np.dtype("int32"): 6,
    np.dtype("float32"): 7,
    np.dtype("float64"): 8,
}
_PACKED_DTYPES = {v: k for k, v in _PACKED_TYPES.items()}


@dataclass(kw_only=True, eq=False)
class PointCloud(Message, schema="foxglove.PointCloud"):
    """Unorganised point cloud: ``points`` (N, 3) float32/float64 in ``frame_id``, optional
    ``normals`` (N, 3) of the same dtype and ``colors`` (N, 3) uint8."""

    WIRE_EXACT: ClassVar[bool] = True
    BULK: ClassVar[int | None] = 6

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"PointCloud.points must be (N, 3), got {self.points.shape}")
        if self.points.dtype not in (np.float32, np.float64):
            self.points = self.points.astype(np.float64)
        if self.normals is not None:
            self.normals = np.asarray(self.normals, dtype=self.points.dtype)
            if self.normals.shape != self.points.shape:
                raise ValueError("PointCloud.normals must have the shape of points")
        if self.colors is not None:
            self.colors = np.asarray(self.colors, dtype=np.uint8)
            if self.colors.shape != self.points.shape:
                raise ValueError("PointCloud.colors must be (N, 3) uint8")

    def _layout(self) -> list[tuple[str, np.ndarray, int]]:
        cols: list[tuple[str, np.ndarray, int]] = [
            ("x", self.points, 0),
            ("y", self.points, 1),
            ("z", self.points, 2),
        ]
        if self.normals is not None:
            cols += [
                ("normal_x", self.normals, 0),
                ("normal_y", self.normals, 1),
                ("normal_z", self.normals, 2),
            ]
        if self.colors is not None:
            cols += [("red", self.colors, 0), ("green", self.colors, 1), ("blue", self.colors, 2)]
        return cols

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id = self.frame_id
        pb.pose.orientation.w = 1.0
        cols = self._layout()
        dtype = np.dtype([(name, arr.dtype) for name, arr, _ in cols])
        offset = 0
        for name, arr, _ in cols:
            pb.fields.add(name=name, offset=offset, type=_PACKED_TYPES[arr.dtype])
            offset += arr.dtype.itemsize
        pb.point_stride = dtype.itemsize
        if len(cols) == 3 and self.points.flags.c_contiguous:
            return pb, _bytes_of(self.points)
        packed = np.empty(len(self.points), dtype=dtype)
        for name, arr, k in cols:
            packed[name] = arr[:, k]
        return pb, _bytes_of(packed)

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        data = bulk if bulk is not None else pb.data
        names = [f.name for f in pb.fields]
        dtype = np.dtype(
            {
                "names": names,
                "formats": [_PACKED_DTYPES[f.type] for f in pb.fields],
                "offsets": [f.offset for f in pb.fields],
                "itemsize": pb.point_stride,
            }
        )
        n = len(data) // pb.point_stride if pb.point_stride else 0
        xyz_t = dtype.fields["x"][0] if "x" in names else np.dtype(np.float32)
        if names == ["x", "y", "z"] and pb.point_stride == 3 * xyz_t.itemsize:
            points = np.frombuffer(data, dtype=xyz_t).reshape(n, 3)
            return cls(stamp_ns=get_stamp(pb), frame_id=pb.frame_id, points=points)
        rec = np.frombuffer(data, dtype=dtype, count=n)

        def stack(keys: tuple[str, str, str]) -> np.ndarray | None:
            if not all(k in names for k in keys):
                return None
            return np.stack([rec[k] for k in keys], axis=1)

        pts = stack(("x", "y", "z"))
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            points=pts if pts is not None else np.zeros((n, 3)),
            normals=stack(("normal_x", "normal_y", "normal_z")),
            colors=stack(("red", "green", "blue")),
        )


_IMAGE_ENCODINGS = {
    "32FC1": (np.float32, 1),
    "64FC1": (np.float64, 1),
    "16UC1": (np.uint16, 1),
    "mono8": (np.uint8, 1),
    "rgb8": (np.uint8, 3),
    "bgr8": (np.uint8, 3),
}


@dataclass(kw_only=True, eq=False)
class Image(Message, schema="foxglove.RawImage"):
    """Raw image (H, W) or (H, W, C). Depth images use encoding ``32FC1`` in metres with NaN for
    invalid pixels."""

    WIRE_EXACT: ClassVar[bool] = True
    BULK: ClassVar[int | None] = 6

    data: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    encoding: str = "32FC1"

    def __post_init__(self) -> None:
        if self.encoding not in _IMAGE_ENCODINGS:
            raise ValueError(f"unsupported image encoding {self.encoding!r}; use one of {sorted(_IMAGE_ENCODINGS)}")
        dt, ch = _IMAGE_ENCODINGS[self.encoding]
        self.data = np.asarray(self.data, dtype=dt)
        if (ch == 1 and self.data.ndim != 2) or (ch > 1 and (self.data.ndim != 3 or self.data.shape[2] != ch)):
            raise ValueError(f"image data shape {self.data.shape} does not fit encoding {self.encoding}")

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id = self.frame_id
        h, w = self.data.shape[:2]
        pb.width, pb.height, pb.encoding = w, h, self.encoding
        pb.step = w * self.data.itemsize * (self.data.shape[2] if self.data.ndim == 3 else 1)
        return pb, _bytes_of(self.data)

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        dt, ch = _IMAGE_ENCODINGS[pb.encoding]
        buf = bulk if bulk is not None else pb.data
        shape = (pb.height, pb.width) if ch == 1 else (pb.height, pb.width, ch)
        data = np.frombuffer(buf, dtype=dt).reshape(shape)
        return cls(stamp_ns=get_stamp(pb), frame_id=pb.frame_id, data=data, encoding=pb.encoding)


@dataclass(kw_only=True, eq=False)
class CameraInfo(Message, schema="foxglove.CameraCalibration"):
    """Pinhole intrinsics of a camera (no distortion unless D is given)."""

    WIRE: ClassVar[WireMap] = {"K": Wire(shape=(3, 3)), "D": Wire(shape=(-1,))}

    width: int = 0
    height: int = 0
    K: np.ndarray = field(default_factory=lambda: np.eye(3))
    D: np.ndarray = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = "plumb_bob"

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb, bulk = super().to_proto()  # and R, P of an unrectified camera (not read back)
        pb.R.extend(np.eye(3).ravel().tolist())
        P = np.zeros((3, 4))
        P[:, :3] = np.asarray(self.K, dtype=float)
        pb.P.extend(P.ravel().tolist())
        return pb, bulk


@dataclass(kw_only=True, eq=False)
class PoseStamped(Message, schema="foxglove.PoseInFrame"):
    """Pose ``T`` (4x4) of an entity in ``frame_id``."""

    WIRE: ClassVar[WireMap] = {"T": "pose"}

    T: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass(kw_only=True, eq=False)
class PoseWithCovarianceStamped(PoseStamped, schema="vgr.v1.PoseWithCovarianceInFrame"):
    """A :class:`PoseStamped` with the 6x6 ``covariance`` of its perturbation (ROS
    ``geometry_msgs/PoseWithCovarianceStamped``): ``(dt, dphi)`` ordered ``(x, y, z, rot x, rot y,
    rot z)``, m and rad, both in ``frame_id``: ``t' = t + dt``, ``R' = exp([dphi]) R``, the decoupled
    perturbation of engine.transforms and of the hand-eye solver's noise model. A subclass of
    PoseStamped, so it feeds every input that takes a pose; on vgr's own schema (Foxglove has no pose
    with covariance), whose first three fields are those of ``foxglove.PoseInFrame``."""

    WIRE: ClassVar[WireMap] = {"covariance": Wire(shape=(6, 6))}

    covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))

    def __post_init__(self) -> None:
        cov = np.asarray(self.covariance, dtype=float)
        if cov.shape != (6, 6):
            raise ValueError(f"PoseWithCovarianceStamped.covariance must be 6x6, got shape {cov.shape}")
        self.covariance = cov


@dataclass(kw_only=True, eq=False)
class Transform(Message, schema="foxglove.FrameTransform"):
    """``T`` = T_parent_child with parent ``frame_id``."""

    WIRE: ClassVar[WireMap] = {
        "frame_id": "parent_frame_id",
        "T": Wire(position="translation", orientation="rotation"),
    }

    child_frame_id: str = ""
    T: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass(kw_only=True, eq=False)
class FrameTransforms(Message, schema="foxglove.FrameTransforms"):
    """A set of transforms (the frame tree of the cell)."""

    transforms: list[Transform] = field(default_factory=list)

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        ts = [Transform.from_proto(t, None) for t in pb.transforms]
        return cls(stamp_ns=ts[0].stamp_ns if ts else 0, transforms=ts)  # the schema has no stamp of its own


@dataclass(kw_only=True, eq=False)
class JointState(Message, schema="foxglove.JointStates"):
    """Joint positions (rad or m), velocities and efforts by joint name."""

    names: list[str] = field(default_factory=list)
    positions: np.ndarray = field(default_factory=lambda: np.zeros(0))
    velocities: np.ndarray | None = None
    efforts: np.ndarray | None = None

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        n = len(self.positions)
        names = self.names or [f"joint{i + 1}" for i in range(n)]
        for i in range(n):
            j = pb.joints.add(name=names[i], position=float(self.positions[i]))
            if self.velocities is not None:
                j.velocity = float(self.velocities[i])
            if self.efforts is not None:
                j.effort = float(self.efforts[i])
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        js = list(pb.joints)
        return cls(
            stamp_ns=get_stamp(pb),
            names=[j.name for j in js],
            positions=np.array([j.position for j in js]),
            velocities=np.array([j.velocity for j in js]) if js and js[0].HasField("velocity") else None,
            efforts=np.array([j.effort for j in js]) if js and js[0].HasField("effort") else None,
        )


@dataclass
class Mesh:
    """A triangle mesh attached to a frame, for the 3D view (``vertices`` (N, 3) m, ``triangles`` (M, 3))."""

    id: str
    frame_id: str
    vertices: np.ndarray
    triangles: np.ndarray
    color: tuple[float, float, float, float] = (0.6, 0.6, 0.65, 1.0)


@dataclass(kw_only=True, eq=False)
class SceneMeshes(Message, schema="foxglove.SceneUpdate"):
    """Meshes of the cell (workpieces, fixtures) for Foxglove's 3D view."""

    meshes: list[Mesh] = field(default_factory=list)

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        for m in self.meshes:
            ent = pb.entities.add(frame_id=m.frame_id, id=m.id, frame_locked=True)
            ent.timestamp.seconds, ent.timestamp.nanos = divmod(int(self.stamp_ns), 1_000_000_000)
            tri = ent.triangles.add()
            tri.pose.orientation.w = 1.0
            v = np.asarray(m.vertices, dtype=float)[np.asarray(m.triangles, dtype=np.int64).reshape(-1)]
            for x, y, z in v.tolist():
                tri.points.add(x=x, y=y, z=z)
            tri.color.r, tri.color.g, tri.color.b, tri.color.a = m.color
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        meshes = []
        stamp = 0
        for ent in pb.entities:
            stamp = stamp or int(ent.timestamp.seconds) * 1_000_000_000 + int(ent.timestamp.nanos)
            for tri in ent.triangles:
                pts = np.array([(p.x, p.y, p.z) for p in tri.points], dtype=float).reshape(-1, 3)
                c = tri.color
                meshes.append(Mesh(ent.id, ent.frame_id, pts, np.arange(len(pts)).reshape(-1, 3), (c.r, c.g, c.b, c.a)))
        return cls(stamp_ns=stamp, meshes=meshes)
