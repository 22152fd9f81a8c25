"""Input checks shared by the calibration loaders and solvers: clear errors, never silent fixes.

A calibration fed NaN, a reflected or sheared "rotation", or millimetres where metres are expected
would return a confident wrong answer; these functions turn such input into a ``ValueError`` that
names the field and sample.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import orthonormalize

F64 = NDArray[np.float64]


def finite_array(name: str, x: ArrayLike, shape: tuple[int | None, ...] | None = None) -> F64:
    """*x* as a float array of the given shape (None = any length); ValueError on NaN/inf/shape."""
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} is not numeric: {exc}") from exc
    if shape is not None and (
        a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape, strict=True))
    ):
        want = "x".join("N" if s is None else str(s) for s in shape)
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        where = np.argwhere(bad)[0].tolist()
        raise ValueError(f"{name} contains NaN or infinity (first at index {where})")
    return a


def as_rotation_stack(
    name: str, R: ArrayLike, *, tol_error: float = 1e-3, tol_silent: float = 1e-6
) -> tuple[F64, float]:
    """Validate an (N, 3, 3) stack of rotations; return (re-orthonormalised stack, worst deviation).

    A deviation ``max |R^T R - I|`` up to *tol_error* (rounding in text files) is repaired by the
    nearest rotation (SVD); the caller reports the worst deviation when above *tol_silent*. A larger
    deviation or a determinant of -1 (a reflection) raises ValueError naming the sample.
    """
    Rs = finite_array(name, R, (None, 3, 3))
    out = np.empty_like(Rs)
    worst = 0.0
    for i, Ri in enumerate(Rs):
        dev = float(np.max(np.abs(Ri.T @ Ri - np.eye(3))))
        det = float(np.linalg.det(Ri))
        if dev > tol_error or det <= 0:
            raise ValueError(
                f"{name}[{i}] is not a rotation matrix: max |R^T R - I| = {dev:.2e}, det = {det:.4f} "
                f"(tolerance {tol_error:.0e}); check the quaternion/matrix order and the source data"
            )
        worst = max(worst, dev)
        out[i] = orthonormalize(Ri) if dev > tol_silent else Ri
    return out, worst


def looks_like_millimetres(values: ArrayLike, metre_limit: float) -> bool:
    """True when the largest magnitude of *values* exceeds *metre_limit* (then they are likely mm)."""
    v = np.asarray(values, dtype=float)
    return bool(v.size and np.max(np.abs(v)) > metre_limit)
