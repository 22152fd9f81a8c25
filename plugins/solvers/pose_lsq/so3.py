"""Jacobians of the SO(3) exponential map (needed for exact analytic least-squares Jacobians).

``exp(phi + d) = exp(J_l(phi) d) exp(phi) = exp(phi) exp(J_r(phi) d)`` to first order in ``d``.
engine.transforms keeps its left Jacobian private; these are the public, tested versions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.transforms import hat

F64 = NDArray[np.float64]


def so3_left_jacobian(phi: ArrayLike) -> F64:
    """J_l(phi) = I + (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2, series near t = 0."""
    phi = np.asarray(phi, dtype=float).reshape(3)
    th = float(np.linalg.norm(phi))
    W = hat(phi)
    if th < 1e-6:
        return np.eye(3) + 0.5 * W + (W @ W) / 6.0
    return np.eye(3) + (1.0 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


def so3_right_jacobian(phi: ArrayLike) -> F64:
    """J_r(phi) = J_l(-phi) = J_l(phi)^T."""
    return so3_left_jacobian(phi).T


def so3_left_jacobian_inv(phi: ArrayLike) -> F64:
    """Inverse of J_l(phi) (so that log(exp(e) exp(phi)) = phi + J_l^-1(phi) e to first order)."""
    return np.linalg.inv(so3_left_jacobian(phi))
