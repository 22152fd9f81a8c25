"""Main-plane extraction (Open3D RANSAC, refined by least squares) and the plane's contour diameter.

Used by the planar-corrected global registration (seed 004: main-plane normal + midpoint of the
contour's farthest point pair) and by the feature-frame matcher (plane normal = Z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import ConvexHull, QhullError

from plugins.registration.determinism import open3d_seeded
from plugins.registration.validation import InvalidInputError


@dataclass
class PlaneFit:
    """Plane ``normal . x = offset`` (unit normal), its inlier indices and the RMS point-plane distance."""

    normal: np.ndarray
    offset: float
    inliers: np.ndarray
    rms_m: float
    centroid: np.ndarray

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of points along the normal."""
        return points @ self.normal - self.offset

    def flipped(self) -> PlaneFit:
        return PlaneFit(-self.normal, -self.offset, self.inliers, self.rms_m, self.centroid)


def fit_plane_lsq(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Total-least-squares plane through *points*: (unit normal, centroid, RMS distance)."""
    c = points.mean(axis=0)
    _, s, Vt = np.linalg.svd(points - c, full_matrices=False)
    n = Vt[2]
    rms = float(s[2] / np.sqrt(max(points.shape[0], 1)))
    return n, c, rms


def segment_main_plane(
    points: np.ndarray,
    *,
    distance_m: float,
    iterations: int = 1000,
    seed: int = 0,
    refine_rounds: int = 2,
    name: str = "cloud",
) -> PlaneFit:
    """Largest plane of *points*: Open3D ``segment_plane`` (seeded, single-threaded) then least-squares
    refinement on the inliers, re-selecting inliers ``refine_rounds`` times. Raises InvalidInputError when
    fewer than 3 inliers are found."""
    if points.shape[0] < 3:
        raise InvalidInputError(f"{name}: a plane needs at least 3 points, got {points.shape[0]}")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    with open3d_seeded(seed):
        model, idx = pcd.segment_plane(distance_threshold=distance_m, ransac_n=3, num_iterations=iterations)
    inl = np.sort(np.asarray(idx, dtype=np.int64))
    if inl.size < 3:
        raise InvalidInputError(f"{name}: no plane found (RANSAC returned {inl.size} inliers)")
    n = np.asarray(model[:3], dtype=float)
    n /= np.linalg.norm(n)
    c = points[inl].mean(axis=0)
    rms = float("nan")
    for _ in range(max(refine_rounds, 1)):
        n_new, c, rms = fit_plane_lsq(points[inl])
        n = n_new if n_new @ n >= 0 else -n_new
        sel = np.flatnonzero(np.abs((points - c) @ n) <= distance_m)
        if sel.size < 3:
            break
        inl = sel
    n, c, rms = fit_plane_lsq(points[inl]) if inl.size >= 3 else (n, c, rms)
    return PlaneFit(normal=n, offset=float(n @ c), inliers=inl, rms_m=rms, centroid=c)


def largest_cluster(points: np.ndarray, eps_m: float, min_points: int = 3) -> np.ndarray:
    """Indices of the largest DBSCAN cluster (Open3D), or all indices if clustering finds nothing."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    labels = np.asarray(pcd.cluster_dbscan(eps=eps_m, min_points=min_points, print_progress=False))
    valid = labels >= 0
    if not np.any(valid):
        return np.arange(points.shape[0])
    counts = np.bincount(labels[valid])
    return np.flatnonzero(labels == int(np.argmax(counts)))


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """3x2 matrix whose columns span the plane orthogonal to *normal* (deterministic choice)."""
    n = normal / np.linalg.norm(normal)
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u)], axis=1)


def farthest_pair(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two points of *points* (projected in the plane of *normal*) farthest apart: the contour
    diameter of seed 004. Exact: the pair lies on the 2-D convex hull, searched exhaustively."""
    B = plane_basis(normal)
    uv = points @ B
    try:
        hull_idx = ConvexHull(uv).vertices
    except (QhullError, ValueError):
        hull_idx = np.arange(points.shape[0])
    h = uv[hull_idx]
    d2 = np.sum((h[:, None, :] - h[None, :, :]) ** 2, axis=2)
    i, j = np.unravel_index(int(np.argmax(d2)), d2.shape)
    return points[hull_idx[i]], points[hull_idx[j]]
