"""Test helpers: fit a rendered cloud back to its mesh, and the error that fit is expected to have.

The fit is Open3D point-to-plane ICP against densely sampled mesh points with their exact normals.
The expected error is the covariance of the unweighted point-to-plane least-squares estimate under the
camera's noise model: each point's range error along its ray (sigma_i) shows in the point-to-plane
residual as ``sigma_i * cos(incidence_i)``, so with ``J_i = [n_i^T, (p_i x n_i)^T]`` (twist (v, w) of
a left perturbation in the camera frame)::

    Cov = (J^T J)^-1 (J^T diag(sigma_i^2 cos^2 theta_i) J) (J^T J)^-1
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from engine.transforms import inv, log_se3
from plugins.sim.camera import DepthCapture, RenderTruth
from plugins.util.workpieces import Workpiece


def fit_part_pose(
    points_cam: np.ndarray,
    workpiece: Workpiece,
    T_cam_part_init: np.ndarray,
    *,
    n_target: int = 400_000,
    max_corr_m: float = 0.004,
    seed: int = 7,
) -> np.ndarray:
    """T_cam_part estimated by point-to-plane ICP (camera points -> dense mesh samples)."""
    pts, nrm = workpiece.sample_points(n_target, np.random.default_rng(seed))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    target.normals = o3d.utility.Vector3dVector(nrm)
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points_cam, dtype=float)))
    T_part_cam = inv(T_cam_part_init)
    for corr in (max_corr_m, max_corr_m / 4):
        result = o3d.pipelines.registration.registration_icp(
            source,
            target,
            corr,
            T_part_cam,
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(
                relative_fitness=1e-12, relative_rmse=1e-12, max_iteration=100
            ),
        )
        T_part_cam = result.transformation
    return inv(T_part_cam)


def expected_covariance(capture: DepthCapture, truth: RenderTruth, part: int = 0) -> np.ndarray:
    """6x6 covariance of the point-to-plane fit of part ``part`` (twist (v, w), camera frame)."""
    sel = truth.part_index == part
    p = truth.points_true[sel]
    n = capture.normals[sel]
    J = np.hstack((n, np.cross(p, n)))
    s = truth.sigma_m[sel] * np.cos(truth.incidence_rad[sel])
    A_inv = np.linalg.inv(J.T @ J)
    return A_inv @ (J.T @ (J * (s**2)[:, None])) @ A_inv


def error_twist(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """Left error twist (v, w) with T_est = exp(xi) @ T_true."""
    return log_se3(T_est @ inv(T_true))


def surface_scene(workpiece: Workpiece, T: np.ndarray | None = None) -> o3d.t.geometry.RaycastingScene:
    """A ray-casting scene of the workpiece's mesh moved by T (default: in its own frame)."""
    V = np.asarray(workpiece.mesh.vertices, dtype=float)
    if T is not None:
        V = V @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3]
    scene = o3d.t.geometry.RaycastingScene()
    F = np.asarray(workpiece.mesh.triangles, dtype=np.uint32)
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F))
    return scene


def on_surface_distance(workpiece: Workpiece, points: np.ndarray, T: np.ndarray | None = None) -> np.ndarray:
    """Distance (m) of points near the surface of the workpiece moved by T, to the mesh, in float64.

    Open3D's ``compute_distance`` runs in float32 and is off by up to ~0.1 mm on the long, thin
    triangles that large planar faces are made of, so this takes only the *facet* from Open3D's
    closest-point query and measures the point-to-plane distance in float64.  Near an edge the
    float32 query can name the neighbouring facet (a point 1e-7 m from one face read 5.7e-6 m from
    the plane of the face next to it), so a point not on its named facet's plane is measured again,
    exactly, against every triangle that shares a vertex with that facet.  Exact for points on or
    very near the surface; use ``compute_distance`` for points far from it.
    """
    T = np.eye(4) if T is None else np.asarray(T, dtype=float)
    V = np.asarray(workpiece.mesh.vertices, dtype=float) @ T[:3, :3].T + T[:3, 3]
    F = np.asarray(workpiece.mesh.triangles)
    scene = surface_scene(workpiece, T)
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    tri = scene.compute_closest_points(o3d.core.Tensor(P.astype(np.float32)))["primitive_ids"].numpy()
    a, b, c = V[F[tri, 0]], V[F[tri, 1]], V[F[tri, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.abs(np.einsum("ij,ij->i", P - a, n))
    for i in np.flatnonzero(d > 1e-7):
        near = np.flatnonzero(np.isin(F, F[tri[i]]).any(axis=1))
        d[i] = min(d[i], point_triangle_distance(P[i], V[F[near]]).min())
    return d


def point_triangle_distance(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Exact distance (float64) from point p (3,) to each triangle of tris (k, 3, 3)."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    plane = np.einsum("ij,ij->i", p - a, n)
    q = p - plane[:, None] * n  # projection onto each triangle's plane
    inside = np.ones(len(tris), dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, q - u), n) >= 0
    edge = np.full(len(tris), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        t = np.clip(np.einsum("ij,ij->i", p - u, e) / np.einsum("ij,ij->i", e, e), 0.0, 1.0)
        edge = np.minimum(edge, np.linalg.norm(p - (u + t[:, None] * e), axis=1))
    return np.where(inside, np.abs(plane), edge)
