"""Input validation for the matchers: turn anything a caller passes into a clean (N, 3) float64 array,
or raise :class:`InvalidInputError` with a reason a person can act on.

The top-level ``register_*`` functions catch :class:`InvalidInputError` and return a ``failed`` result, so
bad input never escapes as an exception and never reaches a solver (NaN would otherwise propagate into
the estimate, and coordinates far outside a workcell overflow small_gicp's 21-bit voxel keys).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import open3d as o3d

from engine import transforms as tf

#: Coordinates beyond this (m) are rejected: a camera cloud of a workpiece never reaches 1 km, and
#: small_gicp's voxel keys overflow for |x| / voxel > 2^20.
MAX_ABS_COORDINATE_M = 1000.0


class InvalidInputError(ValueError):
    """Input a matcher cannot use; ``str(exc)`` is the reason shown to the user."""


def as_points(cloud: Any, *, name: str, min_points: int, drop_non_finite: bool = False) -> np.ndarray:
    """Return *cloud* as a contiguous (N, 3) float64 array or raise :class:`InvalidInputError`.

    Accepts an (N, 3) array-like or an ``open3d.geometry.PointCloud``. Non-finite points are an error
    unless *drop_non_finite* (then they are removed, and the count check applies to what is left).
    """
    if cloud is None:
        raise InvalidInputError(f"{name} cloud is missing (None)")
    if isinstance(cloud, o3d.geometry.PointCloud):
        arr = np.asarray(cloud.points)
    else:
        try:
            arr = np.asarray(cloud)
        except Exception as exc:  # ragged lists and the like
            raise InvalidInputError(f"{name} cloud cannot be read as an array: {exc}") from exc
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InvalidInputError(f"{name} cloud must hold real numbers, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InvalidInputError(f"{name} cloud must have shape (N, 3), got {arr.shape}")
    pts = np.ascontiguousarray(arr, dtype=np.float64)
    finite = None if np.isfinite(pts).all() else np.all(np.isfinite(pts), axis=1)
    n_bad = 0 if finite is None else int(pts.shape[0] - np.count_nonzero(finite))
    if n_bad:
        if not drop_non_finite:
            raise InvalidInputError(
                f"{name} cloud has {n_bad} of {pts.shape[0]} points with NaN/inf coordinates "
                "(drop invalid depth pixels first, or set drop_non_finite=True)"
            )
        pts = pts[finite]
    if pts.shape[0] == 0:
        raise InvalidInputError(f"{name} cloud is empty")
    if pts.shape[0] < min_points:
        raise InvalidInputError(f"{name} cloud has {pts.shape[0]} points, fewer than the {min_points} required")
    big = float(np.max(np.abs(pts)))
    if big > MAX_ABS_COORDINATE_M:
        raise InvalidInputError(
            f"{name} cloud has a coordinate of {big:.3g} m, beyond {MAX_ABS_COORDINATE_M:g} m "
            "(wrong units? vgr works in metres)"
        )
    return pts


def as_initial_transform(T: Any, *, name: str = "T_init") -> np.ndarray:
    """Identity for None, else a validated 4x4 rigid transform (raises :class:`InvalidInputError`).

    Rotations within 1e-5 of orthonormal are accepted and re-orthonormalised (a pose printed with six
    digits is accepted; Sophus inside KISS-ICP aborts the process on a rotation off by 1e-10).
    """
    if T is None:
        return np.eye(4)
    try:
        A = tf.as_transform(T, name=name, tol=1e-5)
    except ValueError as exc:
        raise InvalidInputError(str(exc)) from exc
    return tf.T_from_Rt(tf.orthonormalize(A[:3, :3]), A[:3, 3])


def check_spread(points: np.ndarray, *, name: str, min_extent_m: float) -> None:
    """Reject clouds whose points are (nearly) all in one place or on one line.

    A registration needs a surface; the second-largest principal extent must reach *min_extent_m*.
    """
    centered = points - points.mean(axis=0)
    scatter = centered.T @ centered / max(points.shape[0], 1)
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(scatter), 0.0, None))[::-1]  # principal standard deviations
    if sv[0] < min_extent_m:
        raise InvalidInputError(
            f"{name} cloud spans only {sv[0] * 1e3:.3g} mm (all points at one spot); need >= "
            f"{min_extent_m * 1e3:.3g} mm"
        )
    if sv[1] < min_extent_m:
        raise InvalidInputError(
            f"{name} cloud is a line (second principal extent {sv[1] * 1e3:.3g} mm < "
            f"{min_extent_m * 1e3:.3g} mm); a surface is needed"
        )
