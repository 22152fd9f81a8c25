"""Points drawn uniformly over a triangle mesh's surface, with the caller's random generator.

Used by the simulated parts (plugins/util/workpieces.py) and by the matcher stage that registers a
capture against a part's CAD mesh (plugins/calibration/stages/target_pose.py). Open3D's samplers use a
global seed instead, so a run could not be replayed from its recipe's seed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


def sample_surface(vertices: ArrayLike, triangles: ArrayLike, n: int, rng: np.random.Generator) -> tuple[F64, F64]:
    """``n`` points uniformly distributed over the surface (area-weighted) and their unit normals.

    Returns (points (n, 3), normals (n, 3)) in the mesh's frame; normals follow the triangles'
    winding (outward for a watertight mesh wound counter-clockwise seen from outside).
    """
    if n <= 0:
        raise ValueError(f"sample count must be positive, got {n}")
    V = np.asarray(vertices, dtype=float)
    F = np.asarray(triangles, dtype=np.int64)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cross = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cross, axis=1)
    tri = rng.choice(len(F), size=n, p=area2 / area2.sum())
    r1 = np.sqrt(rng.random(n))
    r2 = rng.random(n)
    w_a, w_b, w_c = 1.0 - r1, r1 * (1.0 - r2), r1 * r2
    points = w_a[:, None] * a[tri] + w_b[:, None] * b[tri] + w_c[:, None] * c[tri]
    normals = cross[tri] / area2[tri, None]
    return points, normals


def read_mesh(path: str | Path) -> o3d.geometry.TriangleMesh:
    """A triangle mesh from any file Open3D reads; ValueError if it holds no triangles."""
    mesh = o3d.io.read_triangle_mesh(str(path))
    if not mesh.has_triangles():
        raise ValueError(f"{path}: no triangle mesh could be read")
    return mesh
