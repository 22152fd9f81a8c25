"""vgr's planar-corrected coarse hypotheses (seed 004, Wei et al. 2024, section 3.2).

For planar weak-geometry parts FPFH descriptors are alike everywhere, and RANSAC returns poses that
are upside down or turned about the plate normal. Seed 004 corrects this with the part's main plane:

1. Fit the main plane of the current and of the template cloud (RANSAC + least squares).
2. Up/down test: align the current normal with the template normal, and with its opposite (flip).
3. Rotation centre: the midpoint of the farthest point pair of the plane's contour, a point fixed to
   the part even when the capture is partial (the centroid is not).
4. Sweep the rotation about the template normal through that centre in ``sweep_step_deg`` steps,
   scoring each candidate by the truncated mean point distance to the template.
5. Keep the best candidates (local minima of the score over the sweep, for both flips) for ICP.

Unlike the paper, vgr keeps several local minima per flip rather than only the best one, so a
symmetric part yields its equivalent poses and the global matcher can report them as ambiguous.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from engine import transforms as tf
from plugins.registration.plane import PlaneFit, farthest_pair, largest_cluster, segment_main_plane
from plugins.registration.preprocess import PreparedCloud
from plugins.registration.validation import InvalidInputError


@dataclass(frozen=True)
class PlanarParams:
    """Planar correction settings; distances default to multiples of the coarse resolution ``res``.

    ``plane_distance_m`` (default ``0.5 res``, at least 0.5 mm): RANSAC/least-squares inlier band.
    ``min_plane_fraction``: the main plane must hold this share of the cloud's points, else the
    method does not apply. ``sweep_step_deg``: 5 in the paper. ``score_points``: evenly strided subset
    of current points used to score the sweep. ``keep``: local minima kept for ICP (over both flips).
    """

    plane_distance_m: float | None = None
    plane_iterations: int = 1000
    min_plane_fraction: float = 0.25
    sweep_step_deg: float = 5.0
    score_points: int = 800
    keep: int = 4


@dataclass
class MainPlane:
    """Main plane of a cloud, oriented, with the seed-004 rotation centre."""

    plane: PlaneFit
    center: np.ndarray
    fraction: float
    diameter_m: float


def main_plane(cloud: PreparedCloud, params: PlanarParams, *, seed: int) -> MainPlane:
    """Fit the main plane and its contour-diameter midpoint; raises InvalidInputError when there is none."""
    res = cloud.resolution()
    dist = params.plane_distance_m or max(0.5 * res, 5e-4)
    fit = segment_main_plane(
        cloud.points, distance_m=dist, iterations=params.plane_iterations, seed=seed, name=cloud.name
    )
    inl_pts = cloud.points[fit.inliers]
    keep = largest_cluster(inl_pts, eps_m=3.0 * res)
    inl_pts = inl_pts[keep]
    fraction = inl_pts.shape[0] / len(cloud)
    if fraction < params.min_plane_fraction:
        raise InvalidInputError(
            f"{cloud.name}: main plane holds {fraction:.0%} of the points, below "
            f"{params.min_plane_fraction:.0%}: not a planar part"
        )
    plane = PlaneFit(fit.normal, fit.offset, fit.inliers[keep], fit.rms_m, inl_pts.mean(axis=0))
    if cloud.viewpoint is not None and plane.distance(np.asarray(cloud.viewpoint, dtype=float)) < 0:
        plane = plane.flipped()  # normal towards the camera (the flip test covers the other case)
    a, b = farthest_pair(inl_pts, plane.normal)
    mid = 0.5 * (a + b)
    mid = mid - plane.distance(mid[None, :])[0] * plane.normal  # on the plane
    return MainPlane(plane=plane, center=mid, fraction=fraction, diameter_m=float(np.linalg.norm(a - b)))


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation taking unit vector a onto unit vector b (shortest arc; Rodrigues)."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.clip(a @ b, -1.0, 1.0))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.eye(3)[int(np.argmin(np.abs(a)))]
        perp = np.cross(a, perp)
        return Rotation.from_rotvec(np.pi * perp / np.linalg.norm(perp)).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def planar_hypotheses(
    current: PreparedCloud,
    template: PreparedCloud,
    params: PlanarParams,
    *,
    seed: int,
    truncation_m: float,
    num_threads: int = 1,
) -> tuple[list[tuple[np.ndarray, str, float]], dict[str, float]]:
    """Candidates ``(T_match, label, sweep score)`` best first, and diagnostics of the two planes."""
    cur = main_plane(current, params, seed=seed)
    tmp = main_plane(template, params, seed=seed)
    n_t, c_t = tmp.plane.normal, tmp.center
    stride = max(1, len(current) // max(params.score_points, 1))
    sample = current.points[::stride]
    n_steps = max(1, round(360.0 / params.sweep_step_deg))
    angles = np.arange(n_steps) * (2.0 * np.pi / n_steps)
    candidates: list[tuple[float, np.ndarray, str]] = []
    for flip, sign in ((0, 1.0), (1, -1.0)):
        R0 = _align(sign * cur.plane.normal, n_t)
        Rs = Rotation.from_rotvec(np.outer(angles, n_t)).as_matrix() @ R0  # (n_steps, 3, 3)
        ts = c_t[None, :] - Rs @ cur.center
        mapped = np.einsum("kij,nj->kni", Rs, sample) + ts[:, None, :]  # all sweep steps at once
        d, _ = template.nearest(mapped.reshape(-1, 3), num_threads=num_threads)
        scores = np.minimum(d, truncation_m).reshape(n_steps, -1).mean(axis=1)
        # local minima over the circular sweep
        left, right = np.roll(scores, 1), np.roll(scores, -1)
        minima = np.flatnonzero((scores <= left) & (scores <= right))
        for k in minima:
            label = f"planar:flip={flip}:angle={np.degrees(angles[k]):.1f}"
            candidates.append((float(scores[k]), tf.T_from_Rt(Rs[k], ts[k]), label))
    candidates.sort(key=lambda c: c[0])
    diag = {
        "current_plane_fraction": cur.fraction,
        "template_plane_fraction": tmp.fraction,
        "current_diameter_m": cur.diameter_m,
        "template_diameter_m": tmp.diameter_m,
        "diameter_difference_m": abs(cur.diameter_m - tmp.diameter_m),
    }
    return [(T, label, s) for s, T, label in candidates[: params.keep]], diag
