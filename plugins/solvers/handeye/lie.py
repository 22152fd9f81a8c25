"""Batched SE(3) helpers for the hand-eye solvers, in the *decoupled* pose perturbation.

``engine.transforms`` owns the single-pose conventions; this module adds what the solvers need on
arrays of poses ``(n, 4, 4)`` and one extra convention, used by the noise model, the
maximum-likelihood refinement and the Cramér–Rao bound:

Decoupled perturbation of a pose ``T = (R, t)`` by ``delta = (dt, dphi)`` (translation first):

    R' = exp([dphi]) R        (rotation perturbed on the left, i.e. about axes of the parent frame)
    t' = t + dt               (translation perturbed in the parent frame)

This is how pose errors are usually specified (a position error in mm and an orientation error in
degrees, both in the frame the pose is expressed in), and it makes the covariance of a translation
directly the covariance of the printed translation vector. ``pose_delta`` is its inverse map.

The ``d_*`` functions return the 6x6 matrices that carry a decoupled perturbation of an operand to
the decoupled perturbation of the result (first order), for products and inverses; chaining them
gives analytic Jacobians of any pose chain.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

F64 = NDArray[np.float64]

__all__ = [
    "as_pose_array",
    "d_inverse",
    "d_product_left",
    "d_product_right",
    "inv_batch",
    "pose_delta",
    "retract",
    "rotation_angles",
    "rotvec_batch",
    "skew_batch",
    "so3_left_jacobian",
    "so3_right_jacobian_inv",
]


def as_pose_array(T: ArrayLike) -> F64:
    """View a 4x4 or a stack of 4x4 poses as float ``(n, 4, 4)`` (no validation)."""
    A = np.asarray(T, dtype=float)
    return A.reshape(-1, 4, 4)


def inv_batch(T: ArrayLike) -> F64:
    """Inverse of each rigid transform in an ``(n, 4, 4)`` stack."""
    T = as_pose_array(T)
    Ti = np.zeros_like(T)
    Rt = np.transpose(T[:, :3, :3], (0, 2, 1))
    Ti[:, :3, :3] = Rt
    Ti[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    Ti[:, 3, 3] = 1.0
    return Ti


def skew_batch(v: ArrayLike) -> F64:
    """``(n, 3)`` vectors -> ``(n, 3, 3)`` skew matrices with ``skew(v) @ u = v x u``."""
    v = np.asarray(v, dtype=float).reshape(-1, 3)
    S = np.zeros((v.shape[0], 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def rotvec_batch(R: ArrayLike) -> F64:
    """Rotation vectors (axis * angle, angle in [0, pi]) of an ``(n, 3, 3)`` stack."""
    return Rotation.from_matrix(np.asarray(R, dtype=float).reshape(-1, 3, 3)).as_rotvec()


def rotation_angles(R: ArrayLike) -> F64:
    """Rotation angles in [0, pi] of an ``(n, 3, 3)`` stack (robust near 0 and pi)."""
    return np.linalg.norm(rotvec_batch(R), axis=1)


def _theta_coeffs(w: F64) -> tuple[F64, F64, F64]:
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    return th, a, b


def so3_left_jacobian(w: ArrayLike) -> F64:
    """Left Jacobian ``J_l(w)`` of SO(3): ``exp(w + d) = exp(J_l(w) d) exp(w)`` to first order."""
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    _, a, b = _theta_coeffs(w)
    W = skew_batch(w)
    return np.eye(3) + a[:, None, None] * W + b[:, None, None] * (W @ W)


def so3_right_jacobian_inv(w: ArrayLike) -> F64:
    """Inverse right Jacobian: ``exp(w) exp(d) = exp(w + J_r^-1(w) d)`` to first order."""
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0 + th**2 / 720.0, 1.0 / ths**2 - 1.0 / (2.0 * ths * np.tan(0.5 * ths)))
    W = skew_batch(w)
    return np.eye(3) + 0.5 * W + c[:, None, None] * (W @ W)


def retract(T: ArrayLike, delta: ArrayLike) -> F64:
    """Apply decoupled perturbations ``delta = (dt, dphi)`` ``(n, 6)`` to poses ``(n, 4, 4)``."""
    T = as_pose_array(T)
    d = np.asarray(delta, dtype=float).reshape(-1, 6)
    out = T.copy()
    out[:, :3, :3] = Rotation.from_rotvec(d[:, 3:]).as_matrix() @ T[:, :3, :3]
    out[:, :3, 3] = T[:, :3, 3] + d[:, :3]
    return out


def pose_delta(T_meas: ArrayLike, T_model: ArrayLike) -> F64:
    """Decoupled difference ``(t_meas - t_model, log(R_meas R_model^T))`` per pose, ``(n, 6)``.

    It is the ``delta`` with ``retract(T_model, delta) == T_meas``.
    """
    Tm = as_pose_array(T_meas)
    Tp = as_pose_array(T_model)
    dR = Tm[:, :3, :3] @ np.transpose(Tp[:, :3, :3], (0, 2, 1))
    return np.concatenate([Tm[:, :3, 3] - Tp[:, :3, 3], rotvec_batch(dR)], axis=1)


def _block(tl: F64, tr: F64, br: F64) -> F64:
    n = tl.shape[0]
    G = np.zeros((n, 6, 6))
    G[:, :3, :3] = tl
    G[:, :3, 3:] = tr
    G[:, 3:, 3:] = br
    return G


def d_product_left(P: ArrayLike, Q: ArrayLike) -> F64:
    """d(P Q) / d(perturbation of P): ``[[I, -[R_P t_Q]x], [0, I]]``, shape ``(n, 6, 6)``."""
    P, Q = np.broadcast_arrays(as_pose_array(P), as_pose_array(Q))
    lever = np.einsum("nij,nj->ni", P[:, :3, :3], Q[:, :3, 3])
    eye = np.broadcast_to(np.eye(3), (P.shape[0], 3, 3))
    return _block(eye, -skew_batch(lever), eye)


def d_product_right(P: ArrayLike) -> F64:
    """d(P Q) / d(perturbation of Q): ``[[R_P, 0], [0, R_P]]``, shape ``(n, 6, 6)``."""
    R = as_pose_array(P)[:, :3, :3]
    return _block(R, np.zeros_like(R), R)


def d_inverse(P: ArrayLike) -> F64:
    """d(P^-1) / d(perturbation of P): ``[[-R^T, -R^T [t]x], [0, -R^T]]``, shape ``(n, 6, 6)``."""
    P = as_pose_array(P)
    Rt = np.transpose(P[:, :3, :3], (0, 2, 1))
    return _block(-Rt, -Rt @ skew_batch(P[:, :3, 3]), -Rt)
