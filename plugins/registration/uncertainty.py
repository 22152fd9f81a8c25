"""Pose uncertainty of a registration from the Gauss-Newton Hessian of point-to-plane residuals.

At the optimum ``T`` (current -> template), each inlier pair (current point ``p`` mapped to the template
frame, template point ``q`` with unit normal ``n``) has the residual ``r = n . (p - q)``. For the left
perturbation ``T' = exp(xi) @ T`` with ``xi = (v, w)`` in the template frame the Jacobian row is
``[n, p x n]``; ``H = J^T J``. Edge pairs of the contour term (edges.py) add rows ``[m, p x m]``
weighted by the ratio of the residual variances.

The covariance vgr reports is NOT the textbook ``s^2 H^-1`` (``s^2 = sum r^2 / (m - 6)``): that one
treats every residual as independent, and on simulated captures (feature_part, 0.1 mm noise, 2 mm
voxels) the true errors reached RMS 3.4 and up to 10.6 of its sigmas per axis, because neighbouring
residuals are correlated (voxel averaging; two captures sampling the surface differently; near the
template pose, the same pixel rays). vgr uses the cluster-robust sandwich ``H^-1 B H^-1`` (``B`` sums
the gradient contributions ``J_i r_i`` over cubes of ``cluster_size_m``, 5 template resolutions by
default, two grids offset by half a cube): RMS 1.1-1.9, worst 5-6 sigma on the same captures; then
a calibration factor ``scale`` (FineParams.sigma_scale = 2.0) measured on simulated captures of four
scenarios (seeds 100 and 200 of tests/registration/test_registration_uncertainty.py's scenes) and
checked on held-out ones (RMS 0.2-1.3 per axis, worst 3.7 sigma). Where its model holds (i.i.d.
noise) the sandwich matches ``s^2 H^-1`` (unit RMS, tested). Neither catches a systematic model error
(a CAD template against a capture: docs/registration.md).

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
from typing import Literal, NamedTuple

import numpy as np

from engine import transforms as tf
from plugins.registration.result import WeakDirection


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


class _GaussNewton(NamedTuple):
    """The Gauss-Newton system at the estimate (template origin): ``H``, the gradient ``g`` of
    0.5 |r|^2, the surface residual variance ``s2``, and per row the point, Jacobian row and weighted
    residual ``w_i r_i`` (for the cluster-robust covariance)."""

    H: np.ndarray
    g: np.ndarray
    s2: float
    rows_p: np.ndarray
    rows_J: np.ndarray
    rows_wr: np.ndarray


class _ScaledHessian(NamedTuple):
    """``H`` moved to the cloud's centre (adjoint ``Ad``) with rotations scaled by ``L`` (``D``): its
    eigen-decomposition ``(lam, V)``, largest eigenvalue, floored eigenvalues and inverse."""

    Ad: np.ndarray
    D: np.ndarray
    lam: np.ndarray
    V: np.ndarray
    lam_max: float
    lam_c: np.ndarray
    H_s_inv: np.ndarray


def point_to_plane_hessian(p: np.ndarray, q: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H = J^T J, residuals) for pairs p -> (q, n), all (m, 3) in the template frame."""
    r = np.einsum("ij,ij->i", n, p - q)
    J = np.hstack([n, np.cross(p, n)])
    return J.T @ J, r


def _jacobian(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.hstack([n, np.cross(p, n)])


def _gauss_newton(
    p: np.ndarray,
    q: np.ndarray,
    n: np.ndarray,
    edges: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    edge_variance_floor: float,
) -> _GaussNewton:
    """Surface rows of the pairs ``p -> (q, n)``, plus the edge rows weighted by ``s^2 / s_e^2``."""
    m = p.shape[0]
    H, r = point_to_plane_hessian(p, q, n)
    J = _jacobian(p, n)
    g = J.T @ r  # gradient of 0.5 |r|^2 at the estimate
    dof = max(m - 6, 1)
    s2 = float(r @ r) / dof
    rows_p, rows_J, rows_wr = p, J, r  # for the cluster-robust covariance: w_i r_i per row
    if edges is not None and edges[0].shape[0] > 0:
        H_e, r_e = point_to_plane_hessian(*edges)
        J_e = _jacobian(edges[0], edges[2])
        s2_e = max(float(r_e @ r_e) / edges[0].shape[0], edge_variance_floor)
        w = s2 / s2_e if s2 > 0 and s2_e > 0 else 1.0
        H = H + w * H_e
        g = g + w * (J_e.T @ r_e)
        rows_p, rows_J, rows_wr = np.vstack([p, edges[0]]), np.vstack([J, J_e]), np.r_[r, w * r_e]
    return _GaussNewton(H, g, s2, rows_p, rows_J, rows_wr)


def _scaled_hessian(H: np.ndarray, center: np.ndarray, L: float) -> _ScaledHessian:
    """Move *H* to *center*, scale rotations by *L*, and invert it through its (floored) eigenvalues."""
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
    H_s_inv = (V / lam_c) @ V.T
    return _ScaledHessian(Ad, D, lam, V, lam_max, lam_c, H_s_inv)


def _cluster_meat(gn: _GaussNewton, hs: _ScaledHessian, center: np.ndarray, cluster_size_m: float) -> np.ndarray:
    """``B`` of the sandwich ``H^-1 B H^-1`` (centre/scaled coordinates): the outer products of the
    summed gradient contributions per cube of *cluster_size_m*, averaged over two grids offset by half
    a cube."""
    G = (gn.rows_J @ hs.Ad @ hs.D) * gn.rows_wr[:, None]  # per-row gradients, centre/scaled coordinates
    B = np.zeros((6, 6))
    for offset in (0.0, 0.5):
        ijk = np.floor((gn.rows_p - center) / cluster_size_m + offset).astype(np.int64)
        ijk -= ijk.min(axis=0)
        dims = ijk.max(axis=0) + 1
        key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]  # one integer per cube
        _, cell = np.unique(key, return_inverse=True)
        S = np.zeros((int(cell.max()) + 1, 6))
        for j in range(6):  # per column: bincount is 10x faster than np.add.at
            S[:, j] = np.bincount(cell, weights=G[:, j], minlength=S.shape[0])
        B += 0.5 * (S.T @ S)
    return B


def _weak_directions(
    hs: _ScaledHessian, ratios: np.ndarray, cov_s: np.ndarray, L: float, weak_ratio: float
) -> list[WeakDirection]:
    """Eigen-directions whose stiffness ratio is below *weak_ratio*, weakest first, with their kind,
    axis (sign fixed: largest component positive) and one-sigma (m or rad)."""
    weak: list[WeakDirection] = []
    for k in np.argsort(hs.lam):
        if ratios[k] >= weak_ratio:
            break
        u = hs.V[:, k]
        t_part, r_part = np.linalg.norm(u[:3]), np.linalg.norm(u[3:])
        sigma_along = float(np.sqrt(max(u @ cov_s @ u, 0.0)))  # in scaled units (m of surface motion)
        kind: Literal["translation", "rotation", "screw"]
        if t_part >= 0.9:
            kind, axis, sigma = "translation", u[:3] / t_part, sigma_along
        elif r_part >= 0.9:
            kind, axis, sigma = "rotation", u[3:] / r_part, sigma_along / L
        else:
            kind, axis, sigma = "screw", u[3:] / max(r_part, 1e-12), sigma_along / L
        if axis[np.argmax(np.abs(axis))] < 0:
            axis = -axis
        weak.append(WeakDirection(kind=kind, axis=axis, ratio=float(max(ratios[k], 0.0)), sigma=sigma))
    return weak


def pose_uncertainty(
    p: np.ndarray,
    q: np.ndarray,
    n: np.ndarray,
    *,
    weak_ratio: float,
    length_scale_m: float | None = None,
    edges: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    edge_variance_floor: float = 0.0,
    cluster_size_m: float | None = None,
    scale: float = 1.0,
) -> PoseUncertainty:
    """Uncertainty of the registration whose inlier pairs are ``p -> (q, n)`` (see module docstring).

    ``weak_ratio``: a direction whose scaled eigenvalue is below ``weak_ratio`` times the largest is
    reported in ``weak_directions``. ``length_scale_m`` defaults to the RMS radius of ``p``.
    ``edges``: edge pairs ``(p_e, q_e, m_e)`` (see edges.py), rows ``m . (p - q)`` with their own
    residual variance ``s_e^2``; they enter as ``(s^2 / s_e^2) J_e^T J_e`` (inverse-variance weights,
    in the units of the surface rows), so ``hessian``, ``covariance = s^2 inv(hessian)`` and
    ``residual_sigma_m`` (the surface one) keep their meaning. ``s_e^2`` is at least
    ``edge_variance_floor``: where a contour lies between two samples is not known better than the
    sampling allows (spacing^2 / 12 per capture), even when two captures happen to sample it alike.

    ``cluster_size_m``: the covariance is the cluster-robust sandwich ``H^-1 B H^-1`` with
    ``B = sum_c (sum_{i in c} w_i J_i r_i)(...)^T`` over cubes of this size (averaged over two grids
    offset by half a cube) instead of ``s^2 H^-1``: residuals of neighbouring points are correlated
    (voxel averaging, the two captures sampling the surface differently), which the i.i.d. formula
    takes for independent information. ``scale`` multiplies every sigma (the calibration factor
    measured on simulated captures, see FineParams.sigma_scale). Neither changes ``hessian``,
    the stiffness ratios or ``stationarity_chi2``.
    """
    gn = _gauss_newton(p, q, n, edges, edge_variance_floor)
    center = p.mean(axis=0)
    L = length_scale_m or float(np.sqrt(np.mean(np.sum((p - center) ** 2, axis=1))))
    L = max(L, 1e-9)
    hs = _scaled_hessian(gn.H, center, L)
    Ad, D, H_s_inv = hs.Ad, hs.D, hs.H_s_inv
    if cluster_size_m is not None and cluster_size_m > 0:
        cov_s = H_s_inv @ _cluster_meat(gn, hs, center, cluster_size_m) @ H_s_inv
    else:
        cov_s = gn.s2 * H_s_inv
    cov_s = scale**2 * 0.5 * (cov_s + cov_s.T)
    cov_c = D @ cov_s @ D
    cov_o = Ad @ cov_c @ Ad.T  # xi_o = Ad xi_c
    cov_o = 0.5 * (cov_o + cov_o.T)
    sig = np.sqrt(np.clip(np.diag(cov_c), 0.0, None))
    # Gauss-Newton step still available at the estimate, in units of its own uncertainty:
    # chi2 = g^T H^-1 g / s^2 (~ chi-square with 6 dof if the estimate is the optimum up to noise).
    g_s = D @ Ad.T @ gn.g
    w = hs.V.T @ g_s
    chi2 = float(np.sum(w**2 / hs.lam_c) / max(gn.s2, 1e-300))
    ratios = hs.lam / hs.lam_max
    weak = _weak_directions(hs, ratios, cov_s, L, weak_ratio)

    return PoseUncertainty(
        hessian=gn.H,
        covariance=cov_o,
        center=center,
        sigma_translation_m=sig[:3],
        sigma_rotation_rad=sig[3:],
        residual_sigma_m=float(np.sqrt(gn.s2)),
        weak_directions=weak,
        eigen_ratios=np.clip(ratios, 0.0, None),
        stationarity_chi2=chi2,
    )
