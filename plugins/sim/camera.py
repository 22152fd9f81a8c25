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
  grows linearly with distance and a bias is a constant shift along each ray. Further range errors
  add to it (each off by default, and then not computed): ``depth_quad_per_m * r_true**2`` (a
  disparity bias of a triangulating camera); a **per-pixel bias pattern** ``bias_pattern``, terms
  ``(i, j, c_m)`` of a polynomial ``sum c x**i y**j`` in the pixel's normalised coordinates
  ``x = (u - cx) / fx``, ``y = (v - cy) / fy`` (a radial pattern ``a rho**2 + b rho**4`` is the terms
  of ``(x**2 + y**2)``); and a ToF's **wiggling** ``wiggle_amplitude_m * sin(2 pi r_true /
  wiggle_period_m + wiggle_phase_rad)``. These are the effects of the depth model-gap workflow
  (plugins/model_gap/depth, docs/depth_gap.md).
* **Depth units.** Real sensors report z as an integer number of depth units (RealSense: 16 bits of
  1 mm by default, 0.1 mm settable); ``depth_unit_m`` > 0 rounds the measured z to that grid (the
  point moves along its ray). The rounding error is uniform, sigma = unit / sqrt(12) (29 um at 0.1 mm).

Everything is vectorised over pixels; the per-frame cost is the BVH build, the ray cast (only rays
inside the parts' projected bounding boxes; for a full scene most of the time, see docs/sim_sensors.md)
and a few array operations on the hit pixels; the organised cloud, normals, pixel coordinates and
per-point truth are assembled only when read.  The same generator gives the same frame (Open3D's ray casting is
deterministic; all random draws come from the caller's ``numpy.random.Generator``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import open3d as o3d

from engine.transforms import as_transform, inv
from plugins.camera.pinhole import CameraModel
from plugins.util.workpieces import Workpiece

# Open3D prints allocator statistics at exit at its default verbosity; vgr's output stays clean.
o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)

__all__ = [
    "DepthCameraModel",
    "DepthCapture",
    "DepthNoiseModel",
    "RenderTruth",
    "default_intrinsics",
    "look_at",
]


def default_intrinsics() -> CameraModel:
    """640 x 480, 60 degrees horizontal field of view, principal point at the image centre."""
    width, height = 640, 480
    f = (width / 2.0) / math.tan(math.radians(60.0) / 2.0)
    return CameraModel.pinhole(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


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
    depth_unit_m: float = 0.0  # reported z is a multiple of this (sensor depth units); 0 = continuous
    depth_quad_per_m: float = 0.0  # range error quad * r**2 (m per m**2; off by default)
    bias_pattern: tuple[tuple[int, int, float], ...] = ()  # per-pixel range bias: terms (i, j, c_m) of c x**i y**j
    wiggle_amplitude_m: float = 0.0  # ToF wiggling amplitude * sin(2 pi r / period + phase); off by default
    wiggle_period_m: float = 0.1874
    wiggle_phase_rad: float = 0.0

    def __post_init__(self) -> None:
        vals = (
            self.sigma_const_m,
            self.sigma_quad_per_m,
            self.grazing_dropout_deg,
            self.dropout_prob,
            self.depth_scale,
            self.depth_bias_m,
            self.depth_unit_m,
            self.depth_quad_per_m,
            self.wiggle_amplitude_m,
            self.wiggle_period_m,
            self.wiggle_phase_rad,
        )
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"depth noise parameters must be finite, got {self}")
        for term in self.bias_pattern:
            if len(term) != 3 or not all(isinstance(k, int) and k >= 0 for k in term[:2]) or not math.isfinite(term[2]):
                raise ValueError(f"bias_pattern terms are (i, j, coefficient_m) with i, j >= 0 integers, got {term}")
        if self.wiggle_period_m <= 0:
            raise ValueError(f"wiggle_period_m must be positive, got {self.wiggle_period_m}")
        if self.sigma_const_m < 0 or self.sigma_quad_per_m < 0:
            raise ValueError("depth noise sigmas must be non-negative")
        if not 0.0 < self.grazing_dropout_deg <= 90.0:
            raise ValueError(f"grazing_dropout_deg must be in (0, 90], got {self.grazing_dropout_deg}")
        if not 0.0 <= self.dropout_prob < 1.0:
            raise ValueError(f"dropout_prob must be in [0, 1), got {self.dropout_prob}")
        if self.depth_scale <= 0:
            raise ValueError(f"depth_scale must be positive, got {self.depth_scale}")
        if self.depth_unit_m < 0:
            raise ValueError(f"depth_unit_m must be >= 0, got {self.depth_unit_m}")

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


@dataclass(eq=False)
class DepthCapture:
    """One depth frame: image, organised cloud and the valid points (camera frame, metres).

    ``organized``, ``normals`` and ``pixels`` are assembled from the valid points on first use and
    then kept: a stage that only publishes the depth image and the cloud does not pay for them.
    """

    depth: np.ndarray  # (H, W) float32 metres along the optical axis, NaN where invalid
    points: np.ndarray  # (N, 3) float64 valid points in the camera frame (m)
    intrinsics: CameraModel
    pixel_index: np.ndarray  # (N,) flat pixel index v * width + u of each valid point
    stamp_ns: int = 0  # time stamp the sensor puts on the frame
    # (normals of the cast rays as Open3D returned them (float32), index of each valid point in them)
    cast_normals: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def valid_mask(self) -> np.ndarray:
        """(H, W) bool, True where the depth is valid."""
        return np.isfinite(self.depth)

    @cached_property
    def organized(self) -> np.ndarray:
        """(H, W, 3) float32 organised cloud, NaN where invalid."""
        k = self.intrinsics
        organized = np.full((k.width * k.height, 3), np.nan, dtype=np.float32)
        organized[self.pixel_index] = self.points
        return organized.reshape(k.height, k.width, 3)

    @cached_property
    def normals(self) -> np.ndarray | None:
        """(N, 3) true surface normals of the valid points, camera frame (float64)."""
        if self.cast_normals is None:
            return None
        normals, index = self.cast_normals
        return normals[index].astype(float)

    @cached_property
    def pixels(self) -> np.ndarray:
        """(N, 2) int32 pixel (u, v) of each valid point."""
        v, u = np.divmod(self.pixel_index.astype(np.int32), np.int32(self.intrinsics.width))
        return np.column_stack((u, v))


@dataclass(eq=False)
class RenderTruth:
    """What the renderer knows and a solver must not: per valid point, noise-free data.

    ``points_true``, ``part_index`` and ``incidence_rad`` are computed on first use.
    """

    T_cam_parts: list[np.ndarray]  # pose of each part in the camera frame
    sigma_m: np.ndarray  # (N,) standard deviation of each point's range error
    z_true: np.ndarray  # (N,) true depth of each valid point (m)
    ray_xy: tuple[np.ndarray, np.ndarray] = field(repr=False)  # x and y of the unit-z ray directions
    cos_incidence: np.ndarray = field(repr=False)  # (N,) cosine of the incidence angle
    geometry_ids: np.ndarray = field(repr=False)  # (N,) Open3D geometry id of each hit
    part_of_geometry: np.ndarray = field(repr=False)  # geometry id -> part index

    @cached_property
    def points_true(self) -> np.ndarray:
        """(N, 3) exact surface points hit by the rays, camera frame."""
        dx, dy = self.ray_xy
        return np.column_stack((dx, dy, np.ones_like(dx))) * self.z_true[:, None]

    @cached_property
    def part_index(self) -> np.ndarray:
        """(N,) index into the ``parts`` sequence of the part each point lies on."""
        return self.part_of_geometry[self.geometry_ids.astype(np.int64)]

    @cached_property
    def incidence_rad(self) -> np.ndarray:
        """(N,) angle between ray and surface normal."""
        return np.arccos(np.clip(self.cos_incidence, -1.0, 1.0))


PartLike = o3d.geometry.TriangleMesh | Workpiece

CULL_MARGIN_PX = 1.0  # rays within this distance of a projected bounding box are cast too (pixels)
CAST_ALL_FRACTION = 0.85  # cast every ray when more than this fraction of the image are candidates


def _mesh_arrays(part: PartLike) -> tuple[np.ndarray, np.ndarray]:
    mesh = part.mesh if isinstance(part, Workpiece) else part
    if not isinstance(mesh, o3d.geometry.TriangleMesh):
        raise TypeError(f"a part must be an open3d TriangleMesh or a Workpiece, got {type(part).__name__}")
    V = np.asarray(mesh.vertices, dtype=float)
    F = np.asarray(mesh.triangles, dtype=np.uint32)
    return V, F


def _build_scene(
    parts: Sequence[tuple[PartLike, np.ndarray]], T_cam_world: np.ndarray
) -> tuple[o3d.t.geometry.RaycastingScene, list[np.ndarray], list[int], list[np.ndarray]]:
    """The parts' meshes in a ray-casting scene in the camera frame, refused if the camera is inside one:
    (the scene; per part its pose in the camera frame, its Open3D geometry id, its 8 bounding-box corners)."""
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
    return scene, T_cam_parts, geometry_ids, boxes


class DepthCameraModel:
    """A depth camera: intrinsics, noise model and working range; :meth:`render` makes a frame."""

    def __init__(
        self,
        intrinsics: CameraModel,
        noise: DepthNoiseModel | None = None,
        min_range_m: float = 0.2,
        max_range_m: float = 2.0,
    ) -> None:
        if not isinstance(intrinsics, CameraModel):
            raise TypeError("intrinsics must be a CameraModel")
        if intrinsics.distorted:
            raise ValueError("the simulated depth camera is an undistorted pinhole: give zero distortion")
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
        # the same float32 values widened to float64 (exact), gathered for the valid points
        self._dx64, self._dy64, self._dir_norm64 = (a.astype(float) for a in (self._dx, self._dy, self._dir_norm))
        self._rays_np = np.concatenate((np.zeros_like(dirs), dirs), axis=1).astype(np.float32)

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
        scene, T_cam_parts, geometry_ids, boxes = _build_scene(parts, inv(T_world_cam))
        cand, hits, t_hit, nrm, cos_inc = self._cast(scene, boxes)
        sub, idx, dx, dy, z_true, sigma, z_meas = self._measure(cand, t_hit, cos_inc, rng)
        points = np.empty((len(sub), 3))
        np.multiply(dx, z_meas, out=points[:, 0])
        np.multiply(dy, z_meas, out=points[:, 1])
        points[:, 2] = z_meas
        k = self.intrinsics
        depth = np.full(k.width * k.height, np.nan, dtype=np.float32)
        depth[idx] = z_meas
        capture = DepthCapture(
            depth=depth.reshape(k.height, k.width),
            points=points,
            intrinsics=k,
            pixel_index=idx,
            stamp_ns=int(stamp_ns),
            cast_normals=(nrm.copy(), sub),  # a copy: no view keeps Open3D's buffers alive
        )
        if not want_truth:
            return capture, None
        part_of_geometry = np.full(max(geometry_ids) + 1, -1, dtype=np.int64)
        part_of_geometry[geometry_ids] = np.arange(len(geometry_ids))
        truth = RenderTruth(
            T_cam_parts=T_cam_parts,
            sigma_m=sigma,
            z_true=z_true,
            ray_xy=(dx, dy),
            cos_incidence=cos_inc[sub].astype(float),
            geometry_ids=hits["geometry_ids"].numpy()[sub],
            part_of_geometry=part_of_geometry,
        )
        return capture, truth

    def _cast(self, scene: o3d.t.geometry.RaycastingScene, boxes: list[np.ndarray]) -> tuple[Any, ...]:
        """Cast the rays :meth:`_candidate_rays` picks: (cand, hits, t_hit, nrm, cos_inc); many back faces: refused."""
        cand, rays, d_norm = self._candidate_rays(boxes)
        hits = scene.cast_rays(rays)
        t_hit = hits["t_hit"].numpy()
        nrm = hits["primitive_normals"].numpy()  # zero for rays that hit nothing
        ray_dirs = rays.numpy()  # (x, y, 1) directions in columns 3-5, float32 as cast
        cos_inc = -(nrm[:, 0] * ray_dirs[:, 3] + nrm[:, 1] * ray_dirs[:, 4] + nrm[:, 2]) / d_norm
        # Back faces: Embree's fast (non-watertight) intersection lets about one ray in a million slip
        # through a shared edge onto the inside of the far wall; such pixels are dropped.  Many of
        # them mean the camera is inside a part or a mesh faces inwards.
        n_back = int(np.count_nonzero(cos_inc < 0.0))
        if n_back > max(10, 0.2 * np.count_nonzero(np.isfinite(t_hit))):
            raise ValueError(
                f"{n_back} rays hit the inside of a part: the camera is inside a part "
                "or a mesh has inward-facing triangles"
            )
        return cand, hits, t_hit, nrm, cos_inc

    def _measure(
        self, cand: np.ndarray | None, t_hit: np.ndarray, cos_inc: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, ...]:
        """Range limits, grazing and random dropouts, range noise, depth scale / bias / units: per point kept, in
        pixel order, (index into the cast rays, pixel index, unit-z ray x and y, true z, sigma, measured z)."""
        noise = self.noise
        ok = (t_hit >= self.min_range_m) & (t_hit <= self.max_range_m)
        ok &= cos_inc >= math.cos(math.radians(noise.grazing_dropout_deg))
        sub = np.flatnonzero(ok)  # into the cast rays, in pixel order
        if noise.dropout_prob > 0.0:
            sub = sub[rng.random(len(sub)) >= noise.dropout_prob]
        idx = sub if cand is None else cand[sub]  # flat pixel index
        z_true = t_hit[sub].astype(float)
        dx, dy, d_norm = self._dx64[idx], self._dy64[idx], self._dir_norm64[idx]
        sigma = noise.sigma(z_true)
        range_meas = z_true * d_norm
        if np.any(sigma > 0):
            range_meas += sigma * rng.standard_normal(len(sub))
        range_meas = noise.depth_scale * range_meas + noise.depth_bias_m
        range_meas = _range_effects(noise, range_meas, z_true * d_norm, dx, dy)
        z_meas = range_meas / d_norm
        if noise.depth_unit_m > 0.0:  # the sensor reports integer depth units (e.g. 16-bit, 0.1 mm)
            z_meas = np.round(z_meas / noise.depth_unit_m) * noise.depth_unit_m
        if np.any(z_meas <= 0.0):  # a huge negative bias pushed points behind the camera: drop them
            ki = np.flatnonzero(z_meas > 0.0)
            sub, idx, dx, dy, z_true, sigma, z_meas = (a[ki] for a in (sub, idx, dx, dy, z_true, sigma, z_meas))
        return sub, idx, dx, dy, z_true, sigma, z_meas

    def _candidate_rays(self, boxes: list[np.ndarray]) -> tuple[np.ndarray | None, o3d.core.Tensor, np.ndarray]:
        """Rays through the pixels inside the projection of some part's bounding box.

        Returns (flat pixel indices of those rays in ascending order, or ``None`` for all pixels; the
        rays; the norms of their unit-z directions, float32).  A ray through a pixel centre outside
        every projected box cannot hit anything, yet costs a fraction of a hit to cast (Open3D's
        per-ray overhead), so only the others are cast: each box projects to the convex polygon of
        its 8 projected corners, taken row by row (:func:`_box_row_spans`) with a margin of
        ``CULL_MARGIN_PX``.  Every ray is cast when a box reaches behind the camera or the candidates
        are most of the image (selecting them would cost more than it saves).  Which rays are cast
        does not change any result.
        """
        k = self.intrinsics
        # Tensors wrap the numpy rays (no copy) for one cast only: a Tensor that Open3D allocated and
        # that lives to the end of the process makes Open3D report a leak and exit with status 1
        everything = None, o3d.core.Tensor.from_numpy(self._rays_np), self._dir_norm
        spans = []
        for corners in boxes:
            if np.any(corners[:, 2] <= 1e-6):
                return everything
            span = _box_row_spans(k.project_camera_points(corners), k.height, k.width, CULL_MARGIN_PX)
            if span is not None:
                spans.append(span)
        if not spans:
            return np.zeros(0, dtype=np.int64), o3d.core.Tensor.from_numpy(self._rays_np[:0]), self._dir_norm[:0]
        r0 = min(v0 for v0, _, _ in spans)
        r1 = max(v0 + len(c0) for v0, c0, _ in spans)
        # +1 where a span starts, -1 after it ends; a running sum > 0 marks the union of the spans
        steps = np.zeros((r1 - r0, k.width + 1), dtype=np.int16)
        for v0, c0, c1 in spans:
            rows = np.arange(v0 - r0, v0 - r0 + len(c0))
            np.add.at(steps, (rows, c0), 1)
            np.add.at(steps, (rows, c1 + 1), -1)
        mask = (np.cumsum(steps, axis=1, dtype=np.int16)[:, : k.width] > 0).ravel()
        if np.count_nonzero(mask) > CAST_ALL_FRACTION * k.width * k.height:
            return everything
        band = slice(r0 * k.width, r1 * k.width)
        cand = np.flatnonzero(mask) + r0 * k.width
        rays = np.compress(mask, self._rays_np[band], axis=0)
        return cand, o3d.core.Tensor.from_numpy(rays), np.compress(mask, self._dir_norm[band])


def _range_effects(
    noise: DepthNoiseModel, range_meas: np.ndarray, range_true: np.ndarray, x: np.ndarray, y: np.ndarray
) -> np.ndarray:
    """*range_meas* with the range-quadratic, per-pixel pattern and wiggling effects added (each only
    when it is on: the default model's output is untouched, bit for bit)."""
    if noise.depth_quad_per_m != 0.0:
        range_meas = range_meas + noise.depth_quad_per_m * range_true**2
    for i, j, c in noise.bias_pattern:
        range_meas = range_meas + c * x**i * y**j
    if noise.wiggle_amplitude_m != 0.0:
        phase = 2.0 * math.pi * range_true / noise.wiggle_period_m + noise.wiggle_phase_rad
        range_meas = range_meas + noise.wiggle_amplitude_m * np.sin(phase)
    return range_meas


# corner i of a box is (x, y, z) = (lo or hi by bits 2, 1, 0 of i); its 12 edges join corners one bit apart
_BOX_EDGES = np.array([(i, i | b) for b in (1, 2, 4) for i in range(8) if not i & b])


def _box_row_spans(uv: np.ndarray, height: int, width: int, margin: float) -> tuple[int, np.ndarray, np.ndarray] | None:
    """Pixel rows and, per row, the first and last pixel column inside the projected box (+ margin).

    ``uv`` are the 8 projected corners (all in front of the camera), so the box's image is their
    convex polygon, whose outline is made of projected box edges.  Row ``v`` keeps the columns whose
    centres lie within ``margin`` of the polygon's part between heights ``v - margin`` and
    ``v + margin``: its left end is the smallest of the edges' crossings at the two heights (clipped
    to the polygon) and of the corners in between (the outline is convex), the right end the largest.
    Returns ``(first row, first columns, last columns)`` (int, inclusive, within the image; a row
    with nothing to keep has last < first), or ``None`` when no row of the image is touched.
    """
    y_min, y_max = float(uv[:, 1].min()), float(uv[:, 1].max())
    v0, v1 = max(0, math.ceil(y_min - margin)), min(height - 1, math.floor(y_max + margin))
    if v1 < v0:
        return None
    v = np.arange(v0, v1 + 1, dtype=float)
    ys = np.stack((np.clip(v - margin, y_min, y_max), np.clip(v + margin, y_min, y_max)))  # (2, rows)
    P, Q = uv[_BOX_EDGES[:, 0]], uv[_BOX_EDGES[:, 1]]
    dy = (Q[:, 1] - P[:, 1])[:, None, None]
    with np.errstate(divide="ignore", invalid="ignore"):  # horizontal edges: their corners count below
        t = (ys[None] - P[:, 1, None, None]) / dy
    on_edge = (t >= 0.0) & (t <= 1.0)
    u = P[:, 0, None, None] + t * (Q[:, 0] - P[:, 0])[:, None, None]
    lo = np.where(on_edge, u, np.inf).min(axis=(0, 1))
    hi = np.where(on_edge, u, -np.inf).max(axis=(0, 1))
    in_band = np.abs(uv[:, 1, None] - v) <= margin  # (8, rows)
    lo = np.minimum(lo, np.where(in_band, uv[:, 0, None], np.inf).min(axis=0)) - margin
    hi = np.maximum(hi, np.where(in_band, uv[:, 0, None], -np.inf).max(axis=0)) + margin
    c0 = np.ceil(np.clip(lo, 0, width)).astype(np.int64)
    c1 = np.floor(np.clip(hi, -1, width - 1)).astype(np.int64)
    c1 = np.maximum(c1, c0 - 1)  # empty rows: nothing to keep
    return v0, c0, c1
