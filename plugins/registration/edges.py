"""Edge-aware refinement for weak geometry: a flat plate seen from above, whose pose in its own plane
the surfaces do not determine.

Why: point-to-plane and GICP residuals only measure distances ALONG surface normals. On a plate
seen from above nearly every normal is the plate normal, so the in-plane pose (x, y and the spin
about the normal) is set by a few tilted normals at the contour, and those are biased by the
sampling: on simulated planar_plate captures (0.1 mm noise, 640 x 480 at 0.4-0.5 m, template
captured at another pose) every ICP backend, even started AT the truth, settles 0.2-1.5 mm /
0.1-1.2 deg away, while reporting a one-sigma of ~0.07 deg (10-20 sigma off). The information is in
the contour: where the surface ENDS. This module measures it.

* Edge points (:func:`edge_set`): points of the full-resolution cloud whose ``neighbours`` nearest
  points (those within ``radius_factor`` x the cloud's typical k-th neighbour distance, projected
  on the local tangent plane) leave an angular gap > ``min_gap_deg`` and whose centre lies off the
  point by > ``min_offset`` x their mean distance: the surface ends there. Each gets the in-plane
  outward direction ``m`` (unit, perpendicular to the surface normal, away from its neighbours). Excluded: OCCLUSION
  boundaries (looking from the viewpoint just past the point, something nearer is seen: the
  surface continues behind an occluder, e.g. the plate around a pin's cap) and points near the
  faces of the ROI crop box (the crop, not the part, ends there).
* Residual of an edge pair (current edge point ``p`` mapped into the template, nearest template
  edge point ``q`` with outward direction ``m``, the two directions within 45 deg):
  ``r = m . (p - q)``, the point-to-line distance in the surface, Jacobian ``[m, p x m]`` like a
  point-to-plane row. Sampled edges lie up to one point spacing inside the true contour, in the
  template and the current capture alike, so the offsets cancel to first order.
* :func:`edge_icp`: Gauss-Newton on point-to-plane rows of the surface cloud (in the final phase
  only those away from the contour, :func:`away_from_edges`) plus edge rows, each
  group weighted by the inverse of its robust (MAD) residual variance, until the step is below the
  fine stage's tolerances or below a tenth of the estimate's own sigma; nearest-edge pairs can flip
  between two neighbours forever, so a step that undoes the previous one ends at the middle of the two.
  Measured on the captures above from 1-2.5 mm / 1-2.5 deg off: 0.03-0.06 mm / 0.003-0.02 deg.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from engine import transforms as tf
from plugins.registration.preprocess import PreparedCloud

EdgeMode = Literal["auto", "on", "off"]

#: edge_icp stops when a Gauss-Newton step is below 0.1 sigma of the estimate (squared, in sigma^2).
STEP_SIGMA2 = 1e-2
#: ... and, out of iterations, accepts an estimate whose last WANDER_STEPS steps all stayed within one
#: sigma: it wanders in its own noise (contour pairs flipping back and forth), it is not diverging
WANDER_STEPS = 6


def settled(recent: list[tuple[np.ndarray, float]], T: np.ndarray) -> tuple[np.ndarray, bool]:
    """After the last iteration: (the mean of the last poses, True) when each of the last
    :data:`WANDER_STEPS` steps was below one sigma of the estimate (``step2 < 1``), else (*T*, False).
    A fine match on the edge of converging, which stops a step short on one CPU and a step later on
    another, is then converged on every CPU; one that still moves by more than its noise is not."""
    last = recent[-WANDER_STEPS:]
    if len(last) < WANDER_STEPS or any(step2 >= 1.0 for _, step2 in last):
        return T, False
    poses = np.array([p for p, _ in last])
    out = np.eye(4)
    out[:3, :3] = Rotation.from_matrix(poses[:, :3, :3]).mean().as_matrix()
    out[:3, 3] = poses[:, :3, 3].mean(axis=0)
    return out, True


@dataclass(frozen=True)
class EdgeParams:
    """Edge term settings (see module docstring).

    ``mode``: ``auto`` adds the edge term when the surfaces leave a weak direction (stiffness ratio
    below ``FineParams.weak_ratio``; a plate seen from above: ~1e-4, feature_part: > 0.05), ``on``
    always, ``off`` never. ``min_fitness``: share of the current edge points that must find a
    template edge (within ``inlier_factor`` x the point spacing, directions within 45 deg) for the
    estimate to be accepted; a wrong pose of a plate leaves most of its contour unmatched (measured:
    > 0.97 at the true pose). ``min_edges``: fewer edge pairs than this and the term is not used.
    """

    mode: EdgeMode = "auto"
    neighbours: int = 32
    radius_factor: float = 1.5
    min_gap_deg: float = 120.0
    min_offset: float = 0.3
    inlier_factor: float = 3.0
    min_fitness: float = 0.5
    min_edges: int = 30
    max_iterations: int = 50
    min_cos: float = 0.7


@dataclass
class EdgeSet:
    """Edge points of one capture (full resolution): ``points``, outward in-plane ``directions``
    and surface ``normals`` (all (n, 3)), the capture's point ``spacing`` (m)."""

    points: np.ndarray
    directions: np.ndarray
    normals: np.ndarray
    spacing: float

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def tree(self) -> cKDTree:
        if not hasattr(self, "_tree"):
            self._tree = cKDTree(self.points)
        return self._tree


def _full_normals(points: np.ndarray, k: int, viewpoint: tuple[float, float, float] | None) -> np.ndarray:
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k))
    if viewpoint is not None:
        pcd.orient_normals_towards_camera_location(np.asarray(viewpoint, dtype=float))
    return np.asarray(pcd.normals)


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(n, e1)


def _lopsided(
    points: np.ndarray,
    normals: np.ndarray,
    tree: cKDTree,
    rows: np.ndarray,
    k: int,
    radius_factor: float,
    min_gap_rad: float,
    min_offset: float,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Border test of points *rows* with their k nearest neighbours: (is border, outward direction,
    median nearest distance, median k-th distance) (see :func:`detect_edges`)."""
    d, idx = tree.query(points[rows], k=k + 1)
    p, n = points[rows], normals[rows]
    # neighbours much farther than a typical k-th neighbour (across a gap or a depth step) do not
    # count: a radius from the k-th distance, not from the nearest one, which is small on irregular
    # sampling and would make points inside look like borders
    kth = float(np.median(d[:, -1]))
    V = points[idx[:, 1:]] - p[:, None, :]
    V -= np.einsum("nkj,nj->nk", V, n)[..., None] * n[:, None, :]
    valid = d[:, 1:] <= radius_factor * kth
    e1, e2 = _tangent_basis(n)
    ang = np.arctan2(np.einsum("nkj,nj->nk", V, e2), np.einsum("nkj,nj->nk", V, e1))
    ang = np.sort(np.where(valid, ang, 10.0), axis=1)  # invalid neighbours last (angles are <= pi)
    cnt = valid.sum(axis=1)
    gaps = np.where(np.arange(1, k)[None, :] < cnt[:, None], np.diff(ang, axis=1), 0.0)
    wrap = ang[:, 0] + 2.0 * np.pi - ang[np.arange(len(rows)), np.maximum(cnt - 1, 0)]
    max_gap = np.maximum(gaps.max(axis=1, initial=0.0), np.where(cnt > 0, wrap, 0.0))
    centre = np.where(valid[..., None], V, 0.0).sum(axis=1) / np.maximum(cnt, 1)[:, None]
    norm_c = np.linalg.norm(centre, axis=1)
    mean_d = np.where(valid, d[:, 1:], 0.0).sum(axis=1) / np.maximum(cnt, 1)
    border = (max_gap > min_gap_rad) & (cnt >= 4) & (norm_c > min_offset * mean_d)
    out = -centre / np.maximum(norm_c, 1e-300)[:, None]
    return border, out, float(np.median(d[:, 1])), kth


def detect_edges(
    points: np.ndarray,
    normals: np.ndarray,
    params: EdgeParams,
    *,
    viewpoint: tuple[float, float, float] | None,
    roi_margin_box: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> EdgeSet:
    """Edge points of *points* (see module docstring). ``roi_margin_box``: (center, rotation,
    half extent) of the ROI crop; points within 2 spacings of its faces are not edges.

    Two passes: a loose one with 8 neighbours on every point (gap > 0.75 ``min_gap_deg``, offset >
    0.5 ``min_offset``) picks candidates, the full test with ``neighbours`` decides. The large
    neighbourhood is what keeps irregular sampling from looking like borders (uniformly random points
    on a plane: 16 neighbours flag 7 % of the inside points, 32 neighbours 0.03 %)."""
    m = points.shape[0]
    tree = cKDTree(points)
    all_rows = np.arange(m)
    pre, _, spacing, _ = _lopsided(
        points,
        normals,
        tree,
        all_rows,
        min(8, m - 1),
        params.radius_factor,
        0.75 * np.radians(params.min_gap_deg),
        0.5 * params.min_offset,
    )
    rows = all_rows[pre]
    out = np.zeros((0, 3))
    if rows.size:
        k = min(params.neighbours, m - 1)
        border, out, _, _ = _lopsided(
            points, normals, tree, rows, k, params.radius_factor, np.radians(params.min_gap_deg), params.min_offset
        )
        rows, out = rows[border], out[border]
    cand = rows
    out_all = np.zeros((m, 3))
    out_all[rows] = out
    out = out_all
    if viewpoint is not None and cand.size:
        # occlusion boundary: just past the point, the sensor sees something nearer
        vp = np.asarray(viewpoint, dtype=float)
        rel = points - vp
        rng = np.linalg.norm(rel, axis=1)
        dirs = rel / np.maximum(rng, 1e-300)[:, None]
        beyond = points[cand] + 1.5 * spacing * out[cand] - vp
        beyond_dir = beyond / np.linalg.norm(beyond, axis=1, keepdims=True)
        ang_r = spacing / np.maximum(rng[cand], 1e-300)
        dd, ii = cKDTree(dirs).query(beyond_dir, k=4, distance_upper_bound=float(np.max(ang_r)))
        hit = np.isfinite(dd) & (dd <= ang_r[:, None])
        ii = np.where(hit, ii, 0)
        nearer = hit & (rng[ii] < rng[cand][:, None] - 3.0 * spacing)
        cand = cand[~nearer.any(axis=1)]
    if roi_margin_box is not None and cand.size:
        c, R, half = roi_margin_box
        local = np.abs((points[cand] - c) @ R)
        cand = cand[np.all(local < half - 2.0 * spacing, axis=1)]
    return EdgeSet(points[cand], out[cand], normals[cand], spacing)


def edge_set(cloud: PreparedCloud, params: EdgeParams) -> EdgeSet:
    """Edge points of *cloud*'s full-resolution points (cached on the cloud)."""
    key = ("edges", params)
    if key not in cloud._cache:
        pts = cloud.full_points if cloud.full_points is not None else cloud.points
        normals = _full_normals(pts, cloud.normal_k, cloud.viewpoint)
        roi = cloud.roi
        box = None
        if roi is not None:
            box = (np.asarray(roi.center), np.asarray(roi.rotation), 0.5 * np.asarray(roi.extent))
        cloud._cache[key] = detect_edges(pts, normals, params, viewpoint=cloud.viewpoint, roi_margin_box=box)
    return cloud._cache[key]


def away_from_edges(cloud: PreparedCloud, edges: EdgeSet, band_factor: float = 1.5) -> np.ndarray:
    """Mask of *cloud*'s points farther than ``band_factor`` resolutions from every edge point of
    *edges* (the same capture's; cached). Where the edge rows speak, the surface rows are left out:
    a point-to-plane row at the contour carries the tilt of a normal fitted across the border (more so
    on voxel centroids), which pulls the in-plane pose by up to 0.3 mm / 0.2 deg on the plate."""
    key = ("away_from_edges", len(edges), edges.spacing, band_factor)
    if key not in cloud._cache:
        if len(edges) == 0:
            cloud._cache[key] = np.ones(len(cloud), dtype=bool)
        else:
            d, _ = edges.tree().query(cloud.points, k=1)
            cloud._cache[key] = d > band_factor * cloud.resolution()
    return cloud._cache[key]


@dataclass
class EdgePairs:
    """Edge correspondences at a pose: current edge points mapped into the template ``p``, template
    edge points ``q``, their outward directions ``m`` (in the surface), and the match share."""

    p: np.ndarray
    q: np.ndarray
    m: np.ndarray
    fitness: float


def edge_pairs(current: EdgeSet, template: EdgeSet, T: np.ndarray, max_distance_m: float, min_cos: float) -> EdgePairs:
    """Pairs within *max_distance_m* whose outward directions agree (cos > *min_cos*)."""
    if len(current) == 0 or len(template) == 0:
        z = np.zeros((0, 3))
        return EdgePairs(z, z, z, 0.0)
    p = tf.transform_points(T, current.points)
    mc = current.directions @ T[:3, :3].T
    d, i = template.tree().query(p, k=1, distance_upper_bound=max_distance_m)
    found = np.isfinite(d)
    i = np.where(found, i, 0)
    mt = template.directions[i]
    ok = found & (np.einsum("ij,ij->i", mc, mt) > min_cos)
    n = template.normals[i[ok]]
    m = mt[ok] - np.einsum("ij,ij->i", mt[ok], n)[:, None] * n
    m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-300)
    return EdgePairs(p[ok], template.points[i[ok]], m, float(np.count_nonzero(ok)) / len(current))


def _robust_var(r: np.ndarray, floor: float) -> float:
    if r.size == 0:
        return floor
    s = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return max(s * s, floor)


def edge_icp(
    phases: list[tuple[PreparedCloud, PreparedCloud, float, float]],
    cur_edges: EdgeSet,
    tmpl_edges: EdgeSet,
    T_init: np.ndarray,
    *,
    iterations: int,
    translation_eps_m: float,
    rotation_eps_rad: float,
    min_cos: float,
    num_threads: int = 1,
) -> tuple[np.ndarray, int, bool]:
    """Gauss-Newton on point-to-plane rows (surface clouds) + edge rows; returns (T, steps, converged).

    *phases*: ``(current, template, surface correspondence distance, edge correspondence distance)``,
    run in turn until the steps are below the tolerances: vgr uses the fine voxel with the fine
    stage's correspondence distance (wide basin), then the evaluation clouds with the evaluation's
    inlier distances, so the final estimate uses the pairs it is evaluated on."""
    T = np.array(T_init, dtype=float)
    total = 0
    converged = False
    edge_floor = max(cur_edges.spacing, tmpl_edges.spacing) ** 2 / 6.0  # sampling of the contours
    for k, (current, template, corr_s, corr_e) in enumerate(phases):
        normals = template.normals()
        # the first phase keeps the surface rows at the contour too (they help the wide basin),
        # the final one leaves them to the edge rows (accuracy; what evaluate uses)
        interior = away_from_edges(template, tmpl_edges) if k == len(phases) - 1 else np.ones(len(template), bool)
        floor = (1e-3 * template.resolution()) ** 2
        centre = current.centroid
        converged = False
        prev: np.ndarray | None = None
        recent: list[tuple[np.ndarray, float]] = []  # (pose after each step, its size in sigma^2)
        for _ in range(iterations):
            total += 1
            P = tf.transform_points(T, current.points)
            d, i = template.nearest(P, num_threads=num_threads)
            ok = (d <= corr_s) & interior[i]
            p, q, n = P[ok], template.points[i[ok]], normals[i[ok]]
            J1 = np.hstack([n, np.cross(p, n)])
            r1 = np.einsum("ij,ij->i", n, p - q)
            e = edge_pairs(cur_edges, tmpl_edges, T, corr_e, min_cos)
            J2 = np.hstack([e.m, np.cross(e.p, e.m)])
            r2 = np.einsum("ij,ij->i", e.m, e.p - e.q)
            w1, w2 = 1.0 / _robust_var(r1, floor), 1.0 / _robust_var(r2, edge_floor)
            H = w1 * (J1.T @ J1) + w2 * (J2.T @ J2)
            g = w1 * (J1.T @ r1) + w2 * (J2.T @ r2)
            try:
                xi = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                return T, total, False
            # the step as seen at the part centre
            dv = xi[:3] + np.cross(xi[3:], tf.transform_points(T, centre[None])[0])
            step2 = float(xi @ H @ xi)
            if prev is not None and step2 < 1.0:
                back = xi + prev
                if float(back @ H @ back) < 0.01 * step2:  # this step undoes the previous one
                    T = tf.exp_se3(0.5 * xi) @ T  # the middle of the 2-cycle
                    converged = True
                    break
            prev = xi
            T = tf.exp_se3(xi) @ T
            recent.append((T, step2))
            small = np.linalg.norm(dv) < translation_eps_m and np.linalg.norm(xi[3:]) < rotation_eps_rad
            # H is the information matrix (inverse-variance weights): xi^T H xi is the step in units
            # of the estimate's own variance: a step below a tenth of a sigma is convergence.
            if small or step2 < STEP_SIGMA2:
                converged = True
                break
        else:  # out of iterations: converged if it only wanders within its noise
            T, converged = settled(recent, T)
    return T, total, converged
