"""Simulated depth camera: ray-cast workpiece meshes into a depth image and an organised point cloud.

This module owns the sensor model of the simulated 3D camera (structured light / stereo / ToF):

* **Geometry.** Pinhole intrinsics, OpenCV camera frame (x right, y down, z forward), pixel centres at
  integer coordinates, no lens distortion.  One ray per pixel through the pixel centre, cast with
  ``open3d.t.geometry.RaycastingScene`` against the parts' meshes expressed in the camera frame.
  The depth image holds z along the optical axis (not the range along the ray), as real depth cameras
  deliver it.
* **Range limits.** A pixel is valid only if the *true* depth lies in ``[min_range_m, max_range_m]``
  (the working range of real sensors is specified in z).  The field of view is the image itself.
* **Grazing dropouts.** Structured light and stereo lose the surface when it is seen edge-on; a hit
  whose incidence angle (between the ray and the surface normal) exceeds ``grazing_dropout_deg`` is
  dropped.  A camera inside a part (or a mesh facing inwards) is refused with an error; the rare ray
  that slips through a shared edge (Embree's fast intersection is not watertight, ~1e-6 of rays)
  and meets the inside of the far wall is dropped.  A slip that meets another outside face gives
  one wrong-depth pixel, much like a real sensor's flying pixel; it is not detected.
* **Noise.** Zero-mean Gaussian error of the range *along the ray* with a depth-dependent standard
  deviation ``sigma(z) = sigma_const_m + sigma_quad_per_m * z**2``.  The quadratic term is the
  triangulation law of stereo / structured light: ``sigma_z = z**2 * sigma_disparity / (f * B)``
  (Intel, "Tuning depth cameras for best performance" / D400 datasheet: RMS error =
  distance**2 x subpixel / (focal length in px x baseline); D415: B = 55 mm, f ~ 970 px at 1280 x 720,
  subpixel ~ 0.08 gives ~ 1.5e-3 / m, i.e. 0.4 mm at 0.5 m, 1.5 mm at 1 m).  Nguyen, Izadi & Lovell
  (3DIMPVT 2012, "Modeling Kinect sensor noise for improved 3D reconstruction and tracking") fit the
  same shape for Kinect v1: sigma_z = 0.0012 + 0.0019 (z - 0.4)**2 m.  Industrial structured light
  such as seed 004's sensor (two 5 MP cameras, 560 mm working distance) quotes ~30 um.  Presets:
  :meth:`DepthNoiseModel.industrial_structured_light`, :meth:`DepthNoiseModel.realsense_d415`,
  :meth:`DepthNoiseModel.kinect_v1`.  Random dropouts with probability ``dropout_prob`` per pixel.
* **Injectable effects** (off by default): ``depth_scale`` and ``depth_bias_m`` act on the measured
  range along the ray, ``r_meas = depth_scale * (r_true + noise) + depth_bias_m``, so a scale error
  grows linearly with distance and a bias is a constant shift along each ray.

Everything is vectorised over pixels; the per-frame cost is the BVH build, the ray cast and a few
array operations on the hit pixels.  The same generator gives the same frame (Open3D's ray casting is
deterministic; all random draws come from the caller's ``numpy.random.Generator``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from engine.transforms import as_transform, inv

from .workpieces import Workpiece

__all__ = [
    "DepthCameraModel",
    "DepthCapture",
    "DepthNoiseModel",
    "PinholeIntrinsics",
    "RenderTruth",
    "default_intrinsics",
    "look_at",
]


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Pinhole camera intrinsics in pixels (OpenCV convention, pixel centres at integers)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if int(self.width) != self.width or int(self.height) != self.height:
            raise ValueError(f"image size must be integral, got {self.width} x {self.height}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height}")
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"intrinsics must be finite, got fx, fy, cx, cy = {vals}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    def K(self) -> np.ndarray:
        """3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def horizontal_fov_rad(self) -> float:
        """Full horizontal field of view through the outer pixel edges."""
        return math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 2) pixel coordinates (u, v)."""
        P = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        return np.column_stack((self.fx * P[:, 0] / P[:, 2] + self.cx, self.fy * P[:, 1] / P[:, 2] + self.cy))


def default_intrinsics() -> PinholeIntrinsics:
    """640 x 480, 60 degrees horizontal field of view, principal point at the image centre."""
    width, height = 640, 480
    f = (width / 2.0) / math.tan(math.radians(60.0) / 2.0)
    return PinholeIntrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam of an OpenCV camera at ``eye`` looking at ``target`` (image "up" towards ``up``)."""
    eye = np.asarray(eye, dtype=float).reshape(3)
    z = np.asarray(target, dtype=float).reshape(3) - eye
    if not np.all(np.isfinite(z)) or np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at needs finite, distinct eye and target points")
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float).reshape(3))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the viewing direction is parallel to 'up'; pass another up vector")
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack((x, np.cross(z, x), z))
    T[:3, 3] = eye
    return T


@dataclass(frozen=True)
class DepthNoiseModel:
    """Depth noise, dropouts and the depth scale/bias effects (see the module docstring)."""

    sigma_const_m: float = 0.0001  # depth sigma = sigma_const_m + sigma_quad_per_m * z**2
    sigma_quad_per_m: float = 0.0
    grazing_dropout_deg: float = 80.0  # rays hitting a surface at incidence > this are dropped
    dropout_prob: float = 0.0  # extra random dropout
    depth_scale: float = 1.0  # injectable effects (off by default)
    depth_bias_m: float = 0.0

    def __post_init__(self) -> None:
        vals = (
            self.sigma_const_m,
            self.sigma_quad_per_m,
            self.grazing_dropout_deg,
            self.dropout_prob,
            self.depth_scale,
            self.depth_bias_m,
        )
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"depth noise parameters must be finite, got {self}")
        if self.sigma_const_m < 0 or self.sigma_quad_per_m < 0:
            raise ValueError("depth noise sigmas must be non-negative")
        if not 0.0 < self.grazing_dropout_deg <= 90.0:
            raise ValueError(f"grazing_dropout_deg must be in (0, 90], got {self.grazing_dropout_deg}")
        if not 0.0 <= self.dropout_prob < 1.0:
            raise ValueError(f"dropout_prob must be in [0, 1), got {self.dropout_prob}")
        if self.depth_scale <= 0:
            raise ValueError(f"depth_scale must be positive, got {self.depth_scale}")

    def sigma(self, z: np.ndarray | float) -> np.ndarray:
        """Standard deviation (m) of the range error at depth z (m)."""
        z = np.asarray(z, dtype=float)
        return self.sigma_const_m + self.sigma_quad_per_m * z * z

    @classmethod
    def noiseless(cls) -> DepthNoiseModel:
        """No noise, no random dropouts (grazing dropouts at 89.9 deg only); for geometry tests."""
        return cls(sigma_const_m=0.0, sigma_quad_per_m=0.0, grazing_dropout_deg=89.9)

    @classmethod
    def industrial_structured_light(cls) -> DepthNoiseModel:
        """Seed 004's class of sensor: ~30 um at 0.56 m (10 um + 6.4e-5 / m * z**2)."""
        return cls(sigma_const_m=1e-5, sigma_quad_per_m=6.4e-5, grazing_dropout_deg=75.0)

    @classmethod
    def realsense_d415(cls) -> DepthNoiseModel:
        """Intel D415 RMS law z**2 * 0.08 / (970 px * 0.055 m) ~ 1.5e-3 / m * z**2, 1 % dropouts."""
        return cls(sigma_const_m=1e-4, sigma_quad_per_m=1.5e-3, grazing_dropout_deg=70.0, dropout_prob=0.01)

    @classmethod
    def kinect_v1(cls) -> DepthNoiseModel:
        """Nguyen et al. 2012 fitted to a + b z**2 over 0.5-2 m: ~1.2 mm at 0.5 m, ~7 mm at 2 m."""
        return cls(sigma_const_m=1.0e-3, sigma_quad_per_m=1.5e-3, grazing_dropout_deg=70.0, dropout_prob=0.02)


@dataclass
class DepthCapture:
    """One depth frame: image, organised cloud and the valid points (camera frame, metres)."""

    depth: np.ndarray  # (H, W) float32 metres along the optical axis, NaN where invalid
    points: np.ndarray  # (N, 3) float64 valid points in the camera frame (m)
    organized: np.ndarray  # (H, W, 3) float32, NaN where invalid
    normals: np.ndarray | None  # (N, 3) true surface normals of the valid points, camera frame
    intrinsics: PinholeIntrinsics
    pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int32))  # (N, 2) (u, v)
    stamp_ns: int = 0  # time stamp the sensor puts on the frame

    @property
    def valid_mask(self) -> np.ndarray:
        """(H, W) bool, True where the depth is valid."""
        return np.isfinite(self.depth)


@dataclass
class RenderTruth:
    """What the renderer knows and a solver must not: per valid point, noise-free data."""

    points_true: np.ndarray  # (N, 3) exact surface points hit by the rays, camera frame
    part_index: np.ndarray  # (N,) index into the ``parts`` sequence of the part each point lies on
    T_cam_parts: list[np.ndarray]  # pose of each part in the camera frame
    sigma_m: np.ndarray  # (N,) standard deviation of each point's range error
    incidence_rad: np.ndarray  # (N,) angle between ray and surface normal


PartLike = o3d.geometry.TriangleMesh | Workpiece


def _mesh_arrays(part: PartLike) -> tuple[np.ndarray, np.ndarray]:
    mesh = part.mesh if isinstance(part, Workpiece) else part
    if not isinstance(mesh, o3d.geometry.TriangleMesh):
        raise TypeError(f"a part must be an open3d TriangleMesh or a Workpiece, got {type(part).__name__}")
    V = np.asarray(mesh.vertices, dtype=float)
    F = np.asarray(mesh.triangles, dtype=np.uint32)
    return V, F


class DepthCameraModel:
    """A depth camera: intrinsics, noise model and working range; :meth:`render` makes a frame."""

    def __init__(
        self,
        intrinsics: PinholeIntrinsics,
        noise: DepthNoiseModel | None = None,
        min_range_m: float = 0.2,
        max_range_m: float = 2.0,
    ) -> None:
        if not isinstance(intrinsics, PinholeIntrinsics):
            raise TypeError("intrinsics must be a PinholeIntrinsics")
        if not (math.isfinite(min_range_m) and math.isfinite(max_range_m)) or not (0.0 <= min_range_m < max_range_m):
            raise ValueError(f"need 0 <= min_range_m < max_range_m, got {min_range_m}, {max_range_m}")
        self.intrinsics = intrinsics
        if noise is not None and not isinstance(noise, DepthNoiseModel):
            raise TypeError("noise must be a DepthNoiseModel")
        self.noise = noise if noise is not None else DepthNoiseModel()
        self.min_range_m = float(min_range_m)
        self.max_range_m = float(max_range_m)
        k = intrinsics
        u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
        # ray directions with unit z: the ray parameter of a hit is its depth
        dirs = np.stack(((u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)), axis=-1).reshape(-1, 3)
        self._dx = dirs[:, 0].astype(np.float32)
        self._dy = dirs[:, 1].astype(np.float32)
        self._dir_norm = np.linalg.norm(dirs, axis=1).astype(np.float32)
        self._rays_np = np.concatenate((np.zeros_like(dirs), dirs), axis=1).astype(np.float32)
        self._rays = o3d.core.Tensor(self._rays_np)

    def render(
        self,
        parts: Sequence[tuple[PartLike, np.ndarray]],
        T_world_cam: np.ndarray,
        rng: np.random.Generator,
    ) -> DepthCapture:
        """Render the parts ``(mesh or workpiece, T_world_part)`` seen from ``T_world_cam``."""
        return self._render(parts, T_world_cam, rng, 0, want_truth=False)[0]

    def render_with_truth(
        self,
        parts: Sequence[tuple[PartLike, np.ndarray]],
        T_world_cam: np.ndarray,
        rng: np.random.Generator,
        stamp_ns: int = 0,
    ) -> tuple[DepthCapture, RenderTruth]:
        """As :meth:`render`, and the noise-free truth of the frame alongside (for tests only)."""
        capture, truth = self._render(parts, T_world_cam, rng, stamp_ns, want_truth=True)
        assert truth is not None
        return capture, truth

    def _render(
        self,
        parts: Sequence[tuple[PartLike, np.ndarray]],
        T_world_cam: np.ndarray,
        rng: np.random.Generator,
        stamp_ns: int,
        want_truth: bool,
    ) -> tuple[DepthCapture, RenderTruth | None]:
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator (every random draw takes a seed)")
        T_world_cam = as_transform(T_world_cam, name="T_world_cam")
        if len(parts) == 0:
            raise ValueError("nothing to render: the scene has no parts")
        T_cam_world = inv(T_world_cam)
        scene = o3d.t.geometry.RaycastingScene()
        T_cam_parts: list[np.ndarray] = []
        geometry_ids: list[int] = []
        boxes: list[np.ndarray] = []
        for i, item in enumerate(parts):
            try:
                part, T_world_part = item
            except (TypeError, ValueError):
                raise TypeError(f"part {i} must be a (mesh or workpiece, T_world_part) pair") from None
            T_cam_part = T_cam_world @ as_transform(T_world_part, name=f"T_world_part of part {i}")
            V, F = _mesh_arrays(part)
            if len(F) == 0:
                raise ValueError(f"part {i} has an empty mesh")
            if not np.all(np.isfinite(V)):
                raise ValueError(f"part {i} has NaN or infinite vertices")
            V_cam = (V @ T_cam_part[:3, :3].T + T_cam_part[:3, 3]).astype(np.float32)
            geometry_ids.append(int(scene.add_triangles(o3d.core.Tensor(V_cam), o3d.core.Tensor(F))))
            T_cam_parts.append(T_cam_part)
            lo, hi = V.min(axis=0), V.max(axis=0)
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            boxes.append(corners @ T_cam_part[:3, :3].T + T_cam_part[:3, 3])

        origin = o3d.core.Tensor(np.zeros((1, 3), dtype=np.float32))
        if bool(scene.compute_occupancy(origin, nsamples=3).numpy()[0] > 0.5):
            raise ValueError("the camera is inside a part: its centre lies within a closed mesh")

        cand, rays = self._candidate_rays(boxes)
        hits = scene.cast_rays(rays)
        t_hit = hits["t_hit"].numpy()
        nrm = hits["primitive_normals"].numpy()  # zero for rays that hit nothing
        dx, dy, d_norm = self._ray_dirs(cand)
        cos_inc = -(nrm[:, 0] * dx + nrm[:, 1] * dy + nrm[:, 2]) / d_norm
        # Back faces: Embree's fast (non-watertight) intersection lets about one ray in a million slip
        # through a shared edge onto the inside of the far wall; such pixels are dropped.  Many of
        # them mean the camera is inside a part or a mesh faces inwards.
        n_back = int(np.count_nonzero(cos_inc < 0.0))
        if n_back > max(10, 0.2 * np.count_nonzero(np.isfinite(t_hit))):
            raise ValueError(
                f"{n_back} rays hit the inside of a part: the camera is inside a part "
                "or a mesh has inward-facing triangles"
            )
        noise = self.noise
        ok = (t_hit >= self.min_range_m) & (t_hit <= self.max_range_m)
        ok &= cos_inc >= math.cos(math.radians(noise.grazing_dropout_deg))
        sub = np.flatnonzero(ok)
        if noise.dropout_prob > 0.0:
            sub = sub[rng.random(len(sub)) >= noise.dropout_prob]

        z_true = t_hit[sub].astype(float)
        dx, dy, d_norm, cos_inc = (a[sub].astype(float) for a in (dx, dy, d_norm, cos_inc))
        sigma = noise.sigma(z_true)
        range_meas = z_true * d_norm
        if np.any(sigma > 0):
            range_meas += sigma * rng.standard_normal(len(sub))
        range_meas = noise.depth_scale * range_meas + noise.depth_bias_m
        z_meas = range_meas / d_norm
        if np.any(z_meas <= 0.0):  # a huge negative bias pushed points behind the camera: drop them
            ki = np.flatnonzero(z_meas > 0.0)
            sub, dx, dy, cos_inc, z_true, sigma, z_meas = (a[ki] for a in (sub, dx, dy, cos_inc, z_true, sigma, z_meas))
        idx = sub if cand is None else cand[sub]
        n = np.take(nrm, sub, axis=0).astype(float)
        points = np.empty((len(sub), 3))
        np.multiply(dx, z_meas, out=points[:, 0])
        np.multiply(dy, z_meas, out=points[:, 1])
        points[:, 2] = z_meas

        k = self.intrinsics
        depth = np.full(k.width * k.height, np.nan, dtype=np.float32)
        depth[idx] = z_meas
        organized = np.full((k.width * k.height, 3), np.nan, dtype=np.float32)
        organized[idx] = points
        pixels = np.column_stack((idx % k.width, idx // k.width)).astype(np.int32)
        capture = DepthCapture(
            depth=depth.reshape(k.height, k.width),
            points=points,
            organized=organized.reshape(k.height, k.width, 3),
            normals=n,
            intrinsics=k,
            pixels=pixels,
            stamp_ns=int(stamp_ns),
        )
        if not want_truth:
            return capture, None
        part_of_geometry = np.full(max(geometry_ids) + 1, -1, dtype=np.int64)
        part_of_geometry[geometry_ids] = np.arange(len(geometry_ids))
        part_index = part_of_geometry[hits["geometry_ids"].numpy()[sub].astype(np.int64)]
        truth = RenderTruth(
            points_true=np.column_stack((dx, dy, np.ones_like(dx))) * z_true[:, None],
            part_index=part_index,
            T_cam_parts=T_cam_parts,
            sigma_m=sigma,
            incidence_rad=np.arccos(np.clip(cos_inc, -1.0, 1.0)),
        )
        return capture, truth

    def _ray_dirs(self, cand: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x and y of the unit-z ray directions and their norms (float32), for all or some pixels."""
        if cand is None:
            return self._dx, self._dy, self._dir_norm
        return self._dx[cand], self._dy[cand], self._dir_norm[cand]

    def _candidate_rays(self, boxes: list[np.ndarray]) -> tuple[np.ndarray | None, o3d.core.Tensor]:
        """Rays through the image rectangle that contains every part's projected bounding box.

        Returns (flat pixel indices of those rays or ``None`` for all pixels, the rays).  Every ray is
        cast when a box reaches behind the camera or the rectangle covers most of the image; otherwise
        only rays that can hit something are cast, which is most of the cost for a small part.
        """
        k = self.intrinsics
        lo = np.array([np.inf, np.inf])
        hi = -lo
        for corners in boxes:
            if np.any(corners[:, 2] <= 1e-6):
                return None, self._rays
            uv = k.project(corners)
            lo = np.minimum(lo, uv.min(axis=0))
            hi = np.maximum(hi, uv.max(axis=0))
        u0, v0 = (max(int(x), 0) for x in np.floor(lo) - 1)
        u1, v1 = (min(int(x), m) for x, m in zip(np.ceil(hi) + 2, (k.width, k.height), strict=True))
        if u1 <= u0 or v1 <= v0:
            return np.zeros(0, dtype=np.int64), self._rays[:0]
        if (u1 - u0) * (v1 - v0) > 0.5 * k.width * k.height:
            return None, self._rays
        rows, cols = np.mgrid[v0:v1, u0:u1]
        cand = (rows * k.width + cols).ravel()
        rays = self._rays_np.reshape(k.height, k.width, 6)[v0:v1, u0:u1].reshape(-1, 6)
        return cand, o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays))
