"""Pose uncertainty of a registration from the Gauss-Newton Hessian of point-to-plane residuals.

At the optimum ``T`` (current -> template), each inlier pair (current point ``p`` mapped to the template
frame, template point ``q`` with unit normal ``n``) has the residual ``r = n . (p - q)``. For the left
perturbation ``T' = exp(xi) @ T`` with ``xi = (v, w)`` in the template frame the Jacobian row is
``[n, p x n]``; ``H = J^T J`` and ``cov = s^2 H^-1`` with ``s^2 = sum r^2 / (m - 6)``. This is the
standard linearised least-squares covariance; it treats residuals as independent, so on real data it is
a lower bound (neighbouring residuals are correlated by the voxel grid and by systematic sensor error).

Weak directions come from the eigen-decomposition of ``H`` moved to the cloud's centre and with
rotations scaled by the cloud radius ``L`` (so a rotation of ``w`` compares with a translation of
``L w``): an eigenvalue far below the largest one marks a direction the geometry hardly constrains
(e.g. a flat plate sliding in its plane or spinning about its normal).

``stationarity_chi2`` measures how far the estimate is from the point-to-plane optimum for the same
correspondences: the Gauss-Newton step still available, in units of the estimate's own covariance
(``g^T H^-1 g / s^2`` with ``g = J^T r``). An estimate at the optimum up to noise gives a value of
the order of 6 (chi-square with 6 degrees of freedom); a backend that stopped early gives more.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine import transforms as tf

from .result import WeakDirection


@dataclass
class PoseUncertainty:
    """Hessian/covariance at the template origin plus per-axis one-sigma at ``center``."""

    hessian: np.ndarray
    covariance: np.ndarray
    center: np.ndarray
    sigma_translation_m: np.ndarray
    sigma_rotation_rad: np.ndarray
    residual_sigma_m: float
    weak_directions: list[WeakDirection]
    eigen_ratios: np.ndarray
    stationarity_chi2: float


def point_to_plane_hessian(p: np.ndarray, q: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H = J^T J, residuals) for pairs p -> (q, n), all (m, 3) in the template frame."""
    r = np.einsum("ij,ij->i", n, p - q)
    J = np.hstack([n, np.cross(p, n)])
    return J.T @ J, r


def _jacobian(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.hstack([n, np.cross(p, n)])


def pose_uncertainty(
    p: np.ndarray,
    q: np.ndarray,
    n: np.ndarray,
    *,
    weak_ratio: float,
    length_scale_m: float | None = None,
) -> PoseUncertainty:
    """Uncertainty of the registration whose inlier pairs are ``p -> (q, n)`` (see module docstring).

    ``weak_ratio``: a direction whose scaled eigenvalue is below ``weak_ratio`` times the largest is
    reported in ``weak_directions``. ``length_scale_m`` defaults to the RMS radius of ``p``.
    """
    m = p.shape[0]
    H, r = point_to_plane_hessian(p, q, n)
    g = _jacobian(p, n).T @ r  # gradient of 0.5 |r|^2 at the estimate
    dof = max(m - 6, 1)
    s2 = float(r @ r) / dof
    center = p.mean(axis=0)
    L = length_scale_m or float(np.sqrt(np.mean(np.sum((p - center) ** 2, axis=1))))
    L = max(L, 1e-9)

    # H at the centre: xi_o = Ad(T_c) xi_c with T_c = translation(center), so H_c = Ad^T H_o Ad.
    T_c = tf.T_from_Rt(np.eye(3), center)
    Ad = tf.adjoint(T_c)
    H_c = Ad.T @ H @ Ad
    D = np.diag([1.0, 1.0, 1.0, 1.0 / L, 1.0 / L, 1.0 / L])
    H_s = D @ H_c @ D  # coordinates (v, L w): both in metres of surface motion
    H_s = 0.5 * (H_s + H_s.T)
    lam, V = np.linalg.eigh(H_s)
    lam_max = float(max(lam[-1], 1e-300))
    floor = lam_max * 1e-12
    lam_c = np.maximum(lam, floor)
    cov_s = s2 * (V / lam_c) @ V.T
    cov_c = D @ cov_s @ D
    cov_o = Ad @ cov_c @ Ad.T  # xi_o = Ad xi_c
    cov_o = 0.5 * (cov_o + cov_o.T)
    sig = np.sqrt(np.clip(np.diag(cov_c), 0.0, None))
    # Gauss-Newton step still available at the estimate, in units of its own uncertainty:
    # chi2 = g^T H^-1 g / s^2 (~ chi-square with 6 dof if the estimate is the optimum up to noise).
    g_s = D @ Ad.T @ g
    w = V.T @ g_s
    chi2 = float(np.sum(w**2 / lam_c) / max(s2, 1e-300))
    ratios = lam / lam_max

    weak: list[WeakDirection] = []
    for k in np.argsort(lam):
        if ratios[k] >= weak_ratio:
            break
        u = V[:, k]
        t_part, r_part = np.linalg.norm(u[:3]), np.linalg.norm(u[3:])
        sigma_along = float(np.sqrt(s2 / lam_c[k]))  # in scaled units (m of surface motion)
        if t_part >= 0.9:
            kind, axis, sigma = "translation", u[:3] / t_part, sigma_along
        elif r_part >= 0.9:
            kind, axis, sigma = "rotation", u[3:] / r_part, sigma_along / L
        else:
            kind, axis, sigma = "screw", u[3:] / max(r_part, 1e-12), sigma_along / L
        if axis[np.argmax(np.abs(axis))] < 0:
            axis = -axis
        weak.append(WeakDirection(kind=kind, axis=axis, ratio=float(max(ratios[k], 0.0)), sigma=sigma))

    return PoseUncertainty(
        hessian=H,
        covariance=cov_o,
        center=center,
        sigma_translation_m=sig[:3],
        sigma_rotation_rad=sig[3:],
        residual_sigma_m=float(np.sqrt(s2)),
        weak_directions=weak,
        eigen_ratios=np.clip(ratios, 0.0, None),
        stationarity_chi2=chi2,
    )
