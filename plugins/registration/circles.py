"""Circular features on a plane: holes (gaps in the plane's points) and pins (caps standing above it),
each located by a least-squares circle fit to its rim points, in plane coordinates.

Holes: the plane's inlier points are rasterised in the plane (cell ~ the point spacing); empty
connected regions not touching the border are hole candidates; the rim is the nearest plane point to
the candidate centre in each of ``rim_bins`` angular sectors; a circle is fitted to the rim.
Pins: points ``pin_min_height_m``..``pin_max_height_m`` above the plane are clustered (DBSCAN); the
cap of each cluster (points near its top) gives the rim as the farthest cap point per sector.
Rim points are biased by up to half a point spacing towards the material (holes look larger, pin caps
smaller), but symmetrically, so the centres are unbiased; radii are reported with that caveat.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy import ndimage
from scipy.optimize import least_squares

_Rim = tuple[np.ndarray, np.ndarray, float]  # points around a hole or pin, estimated centre and radius


@dataclass
class Circle:
    """A fitted circle in plane coordinates ``(u, v)`` (m) with its rim points' RMS residual."""

    center_uv: np.ndarray
    radius_m: float
    rms_m: float
    n_rim: int
    kind: str  # "hole" or "pin"

    @property
    def center_sigma_m(self) -> float:
        """First-order one-sigma of the centre per axis: rms * sqrt(2 / n)."""
        return float(self.rms_m * np.sqrt(2.0 / max(self.n_rim, 1)))


def fit_circle(uv: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Geometric least-squares circle through 2-D points: (centre, radius, RMS radial residual).

    Starts from the algebraic (Kasa) solution, refined with scipy ``least_squares``."""
    if uv.shape[0] < 3:
        raise ValueError(f"a circle needs at least 3 points, got {uv.shape[0]}")
    A = np.column_stack([2.0 * uv, np.ones(uv.shape[0])])
    b = np.sum(uv**2, axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c0 = sol[:2]
    r0 = float(np.sqrt(max(sol[2] + c0 @ c0, 0.0)))

    def resid(x: np.ndarray) -> np.ndarray:
        return np.linalg.norm(uv - x[:2], axis=1) - x[2]

    out = least_squares(resid, np.array([c0[0], c0[1], r0]), method="lm")
    c, r = out.x[:2], float(abs(out.x[2]))
    rms = float(np.sqrt(np.mean(resid(out.x) ** 2)))
    return c, r, rms


def _bins(radius_m: float, spacing_m: float, max_bins: int) -> int:
    """Angular sectors for a rim: about one per point spacing along the circumference (so that every
    sector holds a true rim point), between 8 and *max_bins*."""
    return int(np.clip(round(2.0 * np.pi * radius_m / max(spacing_m, 1e-9)), 8, max_bins))


def _rim(uv: np.ndarray, center: np.ndarray, bins: int, *, outermost: bool) -> np.ndarray:
    """Per angular sector around *center*, the nearest (or farthest) point: the rim of a hole (cap)."""
    d = uv - center
    ang = np.arctan2(d[:, 1], d[:, 0])
    sector = np.floor((ang + np.pi) / (2.0 * np.pi) * bins).astype(np.int64) % bins
    dist = np.linalg.norm(d, axis=1)
    key = -dist if outermost else dist
    order = np.lexsort((key, sector))
    first = np.ones(order.size, dtype=bool)
    first[1:] = sector[order][1:] != sector[order][:-1]
    return uv[order[first]]


def _rim_circles(
    candidates: list[_Rim], kind: str, spacing_m: float, rim_bins: int, radii: tuple[float, float]
) -> list[Circle]:
    """Circles fitted to the rims of candidate (points, estimated centre, estimated radius): a hole's
    rim is its nearest points per sector, a pin cap's its farthest. Candidates whose rim has fewer
    than 8 points, or whose fitted radius lies outside *radii* (min, max), are left out."""
    circles: list[Circle] = []
    for uv, c_est, r_est in candidates:
        rim = _rim(uv, c_est, _bins(r_est, spacing_m, rim_bins), outermost=kind == "pin")
        if rim.shape[0] < 8:
            continue
        c, r, rms = fit_circle(rim)
        if radii[0] <= r <= radii[1]:
            circles.append(Circle(c, r, rms, rim.shape[0], kind))
    return circles


def find_holes(
    plane_uv: np.ndarray,
    *,
    spacing_m: float,
    min_radius_m: float,
    max_radius_m: float,
    rim_bins: int = 180,
) -> list[Circle]:
    """Holes in a plane given its inlier points in plane coordinates (see module docstring)."""
    cell = max(spacing_m, 1e-5) * 1.5
    lo = plane_uv.min(axis=0) - 2 * cell
    ij = np.floor((plane_uv - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 3)
    if shape[0] * shape[1] > 50_000_000:
        raise ValueError("plane too large for the raster at this spacing")
    occ = np.zeros(shape, dtype=bool)
    occ[ij[:, 0], ij[:, 1]] = True
    occ = ndimage.binary_closing(occ, iterations=1)  # close sampling gaps of one cell
    empty, n = ndimage.label(~occ)
    border = set(np.unique(np.concatenate([empty[0], empty[-1], empty[:, 0], empty[:, -1]])).tolist())
    candidates: list[_Rim] = []
    for lab in range(1, n + 1):
        if lab in border:
            continue
        cells = np.argwhere(empty == lab)
        r_est = np.sqrt(cells.shape[0] / np.pi) * cell
        if not (0.5 * min_radius_m <= r_est <= 1.5 * max_radius_m):
            continue
        c_est = lo + (cells.mean(axis=0) + 0.5) * cell
        near = np.linalg.norm(plane_uv - c_est, axis=1) < r_est + 4 * cell
        candidates.append((plane_uv[near], c_est, r_est))
    return _rim_circles(candidates, "hole", spacing_m, rim_bins, (min_radius_m, max_radius_m))


def find_pins(
    points: np.ndarray,
    heights: np.ndarray,
    to_uv: np.ndarray,
    *,
    spacing_m: float,
    min_height_m: float,
    max_height_m: float,
    min_radius_m: float,
    max_radius_m: float,
    cap_band_m: float | None = None,
    rim_bins: int = 180,
) -> list[Circle]:
    """Pins standing on the plane: *heights* are the points' signed distances above the plane and
    ``points @ to_uv`` their plane coordinates (see module docstring)."""
    sel = np.flatnonzero((heights >= min_height_m) & (heights <= max_height_m))
    if sel.size < 8:
        return []
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[sel]))
    labels = np.asarray(pcd.cluster_dbscan(eps=3.0 * spacing_m, min_points=4, print_progress=False))
    band = cap_band_m or max(3.0 * spacing_m, 0.5e-3)
    candidates: list[_Rim] = []
    for lab in range(int(labels.max(initial=-1)) + 1):
        idx = sel[labels == lab]
        h = heights[idx]
        cap = idx[h >= h.max() - band]
        uv = points[cap] @ to_uv
        if uv.shape[0] < 8:
            continue
        c_est = uv.mean(axis=0)
        candidates.append((uv, c_est, float(np.max(np.linalg.norm(uv - c_est, axis=1)))))
    return _rim_circles(candidates, "pin", spacing_m, rim_bins, (min_radius_m, max_radius_m))
