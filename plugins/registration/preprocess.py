"""Point-cloud preprocessing for the matchers (Open3D): ROI crop, outlier removal, voxel downsampling,
normals, and the per-backend state built from one downsampled cloud (Open3D cloud with normals,
small_gicp cloud with normals/covariances and its k-d tree, a k-d tree for scoring).

Everything here is deterministic: Open3D's voxel grid, crop and normal estimation are per-point
operations (results do not depend on the thread count), small_gicp's normal/covariance estimation is
per point too, and we never use small_gicp's multi-threaded voxel grid (documented by small_gicp as
run-to-run non-deterministic). Defaults are sized for workpieces in metres: 2 mm voxels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import open3d as o3d
import small_gicp
from scipy.spatial import cKDTree

from plugins.registration.validation import InvalidInputError, as_points, check_spread


@dataclass(frozen=True)
class RoiBox:
    """Oriented box in the cloud frame: ``center`` (m), full ``extent`` (m) along the box axes, and the
    box axes as the columns of ``rotation`` (identity = axis-aligned)."""

    center: tuple[float, float, float]
    extent: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    @classmethod
    def from_bounds(cls, min_bound: Any, max_bound: Any) -> RoiBox:
        lo, hi = np.asarray(min_bound, dtype=float), np.asarray(max_bound, dtype=float)
        return cls(center=tuple((lo + hi) / 2.0), extent=tuple(hi - lo))

    def to_open3d(self) -> o3d.geometry.OrientedBoundingBox:
        return o3d.geometry.OrientedBoundingBox(
            np.asarray(self.center, dtype=float),
            np.asarray(self.rotation, dtype=float),
            np.asarray(self.extent, dtype=float),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "center": list(self.center),
            "extent": list(self.extent),
            "rotation": [list(r) for r in self.rotation],
        }


@dataclass(frozen=True)
class PreprocessParams:
    """How a raw capture becomes a matcher-ready cloud (metres).

    ``normal_k`` neighbours estimate normals and GICP covariances (PCA; 10 as in small_gicp, which
    was also the most accurate choice on the simulated captures); normals are oriented towards ``viewpoint`` (the
    camera centre in the cloud frame; None leaves Open3D's arbitrary signs). ``outlier_k`` > 0 enables
    Open3D's statistical outlier removal (k neighbours, ``outlier_std_ratio``) before downsampling.
    """

    voxel_size_m: float = 0.002
    normal_k: int = 10
    roi: RoiBox | None = None
    outlier_k: int = 0
    outlier_std_ratio: float = 3.0
    viewpoint: tuple[float, float, float] | None = (0.0, 0.0, 0.0)
    min_points: int = 20
    drop_non_finite: bool = False
    min_extent_m: float = 0.001

    def coarser(self, voxel_size_m: float) -> PreprocessParams:
        """Same settings at another voxel size (ROI/outlier filtering are not repeated)."""
        return PreprocessParams(
            voxel_size_m=voxel_size_m,
            normal_k=self.normal_k,
            roi=None,
            outlier_k=0,
            viewpoint=self.viewpoint,
            min_points=self.min_points,
            drop_non_finite=False,
            min_extent_m=self.min_extent_m,
        )


@dataclass
class PreparedCloud:
    """A validated, downsampled cloud with lazily built per-backend state.

    ``points`` are the downsampled points (m). ``raw_count`` is the input size after validation/ROI.
    ``full_points`` are the validated, cropped and filtered points before downsampling (what the
    full-resolution polish and the edge term use); ``roi`` is the crop box they were cut with.
    """

    points: np.ndarray
    voxel_size_m: float
    normal_k: int
    viewpoint: tuple[float, float, float] | None
    raw_count: int
    name: str = "cloud"
    full_points: np.ndarray | None = field(default=None, repr=False)
    roi: RoiBox | None = None
    _cache: dict[Any, Any] = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def centroid(self) -> np.ndarray:
        return self.points.mean(axis=0)

    def at_voxel(self, voxel_size_m: float) -> PreparedCloud:
        """The same capture at another voxel size (0 = every point), from ``full_points`` (cached)."""
        key = ("voxel", float(voxel_size_m))
        if key not in self._cache:
            src = self.full_points if self.full_points is not None else self.points
            self._cache[key] = PreparedCloud(
                points=voxel_downsample(src, voxel_size_m),
                voxel_size_m=float(voxel_size_m),
                normal_k=self.normal_k,
                viewpoint=self.viewpoint,
                raw_count=self.raw_count,
                name=self.name,
                full_points=src,
                roi=self.roi,
            )
        return self._cache[key]

    def open3d(self) -> o3d.geometry.PointCloud:
        """Open3D cloud with oriented PCA normals (k nearest neighbours)."""
        if "o3d" not in self._cache:
            pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
            pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(self.normal_k))
            if self.viewpoint is not None:
                pcd.orient_normals_towards_camera_location(np.asarray(self.viewpoint, dtype=float))
            self._cache["o3d"] = pcd
        return self._cache["o3d"]

    def normals(self) -> np.ndarray:
        """Unit normals (N, 3): small_gicp's if that state exists already, else Open3D's."""
        if "small_gicp" in self._cache:
            return np.asarray(self._cache["small_gicp"][0].normals())[:, :3]
        return np.asarray(self.open3d().normals)

    def small_gicp(self, num_threads: int = 1) -> tuple[Any, Any]:
        """(small_gicp.PointCloud with normals + covariances, small_gicp.KdTree)."""
        if "small_gicp" not in self._cache:
            pc = small_gicp.PointCloud(self.points)
            tree = small_gicp.KdTree(pc, num_threads)
            small_gicp.estimate_normals_covariances(pc, tree, self.normal_k, num_threads)
            self._cache["small_gicp"] = (pc, tree)
        return self._cache["small_gicp"]

    def kdtree(self) -> cKDTree:
        """scipy k-d tree of ``points`` (for scoring and correspondences)."""
        if "kdtree" not in self._cache:
            self._cache["kdtree"] = cKDTree(self.points)
        return self._cache["kdtree"]

    def nearest(self, query: np.ndarray, num_threads: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(distance, index) of the nearest point of this cloud for each query point (exact search with
        small_gicp's k-d tree, twice as fast as scipy's: the GICP one when it is built already, else
        a bare tree built once; single-threaded build, so the same tree every time)."""
        if "small_gicp" in self._cache:
            tree = self._cache["small_gicp"][1]
        else:
            if "nn_tree" not in self._cache:
                self._cache["nn_tree"] = small_gicp.KdTree(small_gicp.PointCloud(self.points), 1)
            tree = self._cache["nn_tree"]
        idx, sq = tree.batch_nearest_neighbor_search(query, num_threads)
        return np.sqrt(np.asarray(sq, dtype=float)), np.asarray(idx, dtype=np.int64)

    def spacing(self) -> float:
        """Median distance (m) from a point to its nearest neighbour: the cloud's resolution."""
        if "spacing" not in self._cache:
            d, _ = self.kdtree().query(self.points, k=2)
            self._cache["spacing"] = float(np.median(d[:, 1]))
        return self._cache["spacing"]

    def resolution(self) -> float:
        """The larger of the voxel size and the point spacing (m): the unit for default distances."""
        return max(self.voxel_size_m, self.spacing())

    def radius(self) -> float:
        """RMS distance of the points from their centroid (m): the lever arm of rotations."""
        return float(np.sqrt(np.mean(np.sum((self.points - self.centroid) ** 2, axis=1))))


def crop(points: np.ndarray, roi: RoiBox) -> np.ndarray:
    """Points inside the oriented box (Open3D)."""
    idx = roi.to_open3d().get_point_indices_within_bounding_box(o3d.utility.Vector3dVector(points))
    return points[np.sort(np.asarray(idx, dtype=np.int64))]


def remove_outliers(points: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    """Open3D statistical outlier removal: drop points whose mean distance to k neighbours is large."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    _, idx = pcd.remove_statistical_outlier(nb_neighbors=k, std_ratio=std_ratio)
    return points[np.sort(np.asarray(idx, dtype=np.int64))]


def voxel_downsample(points: np.ndarray, voxel_size_m: float) -> np.ndarray:
    """Open3D voxel-grid downsampling (centroid per occupied voxel); no-op for voxel <= 0."""
    if voxel_size_m <= 0:
        return points.copy()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    return np.asarray(pcd.voxel_down_sample(voxel_size_m).points).copy()


def prepare_cloud(cloud: Any, params: PreprocessParams | None = None, *, name: str = "cloud") -> PreparedCloud:
    """Validate, crop, de-noise and downsample *cloud*; raise :class:`InvalidInputError` with a reason.

    *cloud* may already be a :class:`PreparedCloud` at the same voxel size (returned unchanged), which
    is how a template prepared once is reused by every match.
    """
    params = params or PreprocessParams()
    if isinstance(cloud, PreparedCloud):
        if abs(cloud.voxel_size_m - params.voxel_size_m) <= 1e-12 and cloud.normal_k == params.normal_k:
            return cloud
        # already cropped and filtered: downsample its full-resolution points again (cached on it)
        key = ("prepared", params.voxel_size_m, params.normal_k, params.viewpoint, params.min_points)
        if key not in cloud._cache:
            src = cloud.full_points if cloud.full_points is not None else cloud.points
            sub = prepare_cloud(src, params.coarser(params.voxel_size_m), name=name)
            sub.roi = cloud.roi
            cloud._cache[key] = sub
        return cloud._cache[key]
    if not (np.isfinite(params.voxel_size_m) and params.voxel_size_m >= 0):
        raise InvalidInputError(f"voxel size must be a finite number >= 0, got {params.voxel_size_m}")
    pts = as_points(cloud, name=name, min_points=params.min_points, drop_non_finite=params.drop_non_finite)
    if params.roi is not None:
        pts = crop(pts, params.roi)
        if pts.shape[0] < params.min_points:
            raise InvalidInputError(
                f"{name} cloud has {pts.shape[0]} points inside the ROI, fewer than {params.min_points} "
                "(part missing or ROI misplaced?)"
            )
    if params.outlier_k > 0 and pts.shape[0] > params.outlier_k:
        pts = remove_outliers(pts, params.outlier_k, params.outlier_std_ratio)
    raw_count = int(pts.shape[0])
    check_spread(pts[:: max(1, raw_count // 20000)], name=name, min_extent_m=params.min_extent_m)
    down = voxel_downsample(pts, params.voxel_size_m)
    min_after = max(params.min_points, params.normal_k)
    if down.shape[0] < min_after:
        raise InvalidInputError(
            f"{name} cloud has {down.shape[0]} points after {params.voxel_size_m * 1e3:.3g} mm voxel "
            f"downsampling, fewer than {min_after} (cloud too small for the voxel size?)"
        )
    check_spread(down, name=name, min_extent_m=params.min_extent_m)
    return PreparedCloud(
        points=down,
        voxel_size_m=params.voxel_size_m,
        normal_k=params.normal_k,
        viewpoint=params.viewpoint,
        raw_count=raw_count,
        name=name,
        full_points=pts,
        roi=params.roi,
    )
