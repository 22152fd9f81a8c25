"""Rigid transforms in SE(3) and SO(3): vgr's one geometry module and its frame conventions.

Conventions (docs/design.md, not optional):

* ``T_a_b`` is the pose of frame *b* in frame *a*; it maps points from *b* to *a*:
  ``p_a = T_a_b @ p_b``.  Chains therefore read left to right: ``T_a_c = T_a_b @ T_b_c``.
* Units are metres and radians inside the code.
* Quaternions are ``(x, y, z, w)`` (scipy's order), unit norm, ``w >= 0`` when we produce them.
* Twists / tangent vectors are ``xi = (v, w)``: translation part first, rotation part second,
  with the *left* (world-frame) perturbation ``T' = exp(xi) @ T`` unless a function says otherwise.
* The solvers' *decoupled* perturbation of a pose ``T = (R, t)`` by ``delta = (dt, dphi)``:
  ``R' = exp([dphi]) R``, ``t' = t + dt``, both in the parent frame (how pose errors are usually
  specified: a position error in mm and an orientation error in degrees). :func:`retract` applies
  it, :func:`pose_delta` is its inverse, and the ``d_*`` functions carry it through products and
  inverses (first order), so chaining them gives analytic Jacobians of any pose chain.

Shapes: functions that say so take one pose ``(4, 4)`` / rotation ``(3, 3)`` / vector ``(3,)`` or a
stack ``(n, 4, 4)`` / ``(n, 3, 3)`` / ``(n, 3)`` and return the matching shape.

What is delegated and what is ours: scipy.spatial.transform.Rotation does every rotation
conversion, exp and log of SO(3) (batched, robust near 0 and pi). What remains here is what scipy
does not have: SE(3) glue (inverse, exp/log, adjoint in the ``(v, w)`` order), the SO(3) Jacobians
of the exponential map and the decoupled-perturbation Jacobians the solvers differentiate with.
pytransform3d has Jacobians and adjoints too, but orders twists ``(w, v)`` and works one pose at a
time, so adopting it would mean reordering every caller's twists and losing the batch forms.
Robot-vendor 6-vectors (UR, ABB, KUKA) are not here: the robot adapters convert them
(:mod:`plugins.vendor_poses`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

F64 = NDArray[np.float64]

__all__ = [
    "Rotation",
    "T_from_Rt",
    "T_from_pose7",
    "T_from_rotvec",
    "adjoint",
    "angle_between",
    "as_pose_array",
    "as_transform",
    "check_rotation",
    "d_inverse",
    "d_product_left",
    "d_product_right",
    "euler_zyx_from_R",
    "exp_se3",
    "exp_so3",
    "hat",
    "inv",
    "is_rotation",
    "log_se3",
    "log_so3",
    "orthonormalize",
    "pose7_from_T",
    "pose_delta",
    "pose_error",
    "quat_xyzw_from_R",
    "retract",
    "rotation_angles",
    "rotvec_from_R",
    "so3_left_jacobian",
    "so3_left_jacobian_inv",
    "so3_right_jacobian",
    "so3_right_jacobian_inv",
    "transform_points",
]


# --------------------------------------------------------------------------- construction


def T_from_Rt(R: ArrayLike, t: ArrayLike) -> F64:
    """Homogeneous 4x4 from a 3x3 rotation and a translation 3-vector."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def T_from_rotvec(rotvec: ArrayLike, t: ArrayLike = (0.0, 0.0, 0.0)) -> F64:
    """4x4 from a rotation vector (axis * angle, rad) and a translation (m)."""
    return T_from_Rt(Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix(), t)


def T_from_pose7(position: ArrayLike, quat_xyzw: ArrayLike) -> F64:
    """4x4 from position (m) and unit quaternion (x, y, z, w); the quaternion is normalised."""
    q = np.asarray(quat_xyzw, dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"quaternion {q} has no direction")
    return T_from_Rt(Rotation.from_quat(q / n).as_matrix(), position)


def pose7_from_T(T: ArrayLike) -> tuple[F64, F64]:
    """(position, quaternion xyzw with w >= 0) of a 4x4."""
    T = as_transform(T)
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return T[:3, 3].copy(), q


def _finite_square(A: ArrayLike, n: int, name: str) -> F64:
    """*A* as a float n x n array of finite numbers; ValueError naming *name* otherwise."""
    M = np.asarray(A, dtype=float)
    if M.shape != (n, n):
        raise ValueError(f"{name} must be {n}x{n}, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} contains NaN or infinity")
    return M


def as_transform(T: ArrayLike, *, name: str = "transform", tol: float = 1e-6) -> F64:
    """Validate and return a float 4x4 rigid transform; raise ValueError naming *name* otherwise."""
    A = _finite_square(T, 4, name)
    if not np.allclose(A[3], (0.0, 0.0, 0.0, 1.0), atol=tol):
        raise ValueError(f"{name} last row must be [0, 0, 0, 1], got {A[3]}")
    check_rotation(A[:3, :3], name=f"{name} rotation", tol=tol)
    return A


# --------------------------------------------------------------------------- rotations


def is_rotation(R: ArrayLike, tol: float = 1e-6) -> bool:
    """True when R is a finite 3x3 with R^T R = I and det R = +1 within *tol*."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R.T @ R, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)


def check_rotation(R: ArrayLike, *, name: str = "rotation", tol: float = 1e-6) -> F64:
    """Return R as float 3x3 or raise ValueError saying how far it is from a rotation."""
    A = _finite_square(R, 3, name)
    ortho = float(np.max(np.abs(A.T @ A - np.eye(3))))
    det = float(np.linalg.det(A))
    if ortho > tol or abs(det - 1.0) > tol:
        raise ValueError(
            f"{name} is not a rotation: max |R^T R - I| = {ortho:.2e}, det = {det:.6f} (tolerance {tol:.0e})"
        )
    return A


def orthonormalize(R: ArrayLike) -> F64:
    """Nearest rotation matrix (Frobenius) via SVD, with det = +1."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _vectors(w: ArrayLike) -> F64:
    """A stack ``(n, 3)`` as it is, anything else holding 3 numbers as ``(3,)``."""
    w = np.asarray(w, dtype=float)
    return w if w.ndim == 2 and w.shape[1] == 3 else w.reshape(3)


def hat(w: ArrayLike) -> F64:
    """Skew-symmetric matrix [w]x such that hat(w) @ v = w x v; ``(3,)`` -> ``(3, 3)``, ``(n, 3)`` -> ``(n, 3, 3)``."""
    w = _vectors(w)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    S = np.zeros((*w.shape[:-1], 3, 3))
    S[..., 0, 1], S[..., 0, 2] = -z, y
    S[..., 1, 0], S[..., 1, 2] = z, -x
    S[..., 2, 0], S[..., 2, 1] = -y, x
    return S


def exp_so3(w: ArrayLike) -> F64:
    """Rotation matrix of the rotation vector w; ``(3,)`` -> ``(3, 3)``, ``(n, 3)`` -> ``(n, 3, 3)``."""
    return Rotation.from_rotvec(_vectors(w)).as_matrix()


def log_so3(R: ArrayLike) -> F64:
    """Rotation vector (angle in [0, pi]) of R, ``(3, 3)`` -> ``(3,)`` or ``(n, 3, 3)`` -> ``(n, 3)``
    (robust near 0 and pi: scipy goes through the quaternion)."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


def rotation_angles(R: ArrayLike) -> F64:
    """Rotation angles in [0, pi] of an ``(n, 3, 3)`` stack (robust near 0 and pi)."""
    return np.linalg.norm(log_so3(np.asarray(R, dtype=float).reshape(-1, 3, 3)), axis=1)


def rotvec_from_R(R: ArrayLike) -> F64:
    """Alias of :func:`log_so3` for readability at call sites that speak of rotation vectors."""
    return log_so3(R)


def quat_xyzw_from_R(R: ArrayLike) -> F64:
    """Unit quaternion (x, y, z, w) with w >= 0."""
    q = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    return -q if q[3] < 0 else q


def euler_zyx_from_R(R: ArrayLike) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad for R = Rz(yaw) Ry(pitch) Rx(roll) (intrinsic ZYX)."""
    yaw, pitch, roll = Rotation.from_matrix(np.asarray(R, dtype=float)).as_euler("ZYX")
    return float(roll), float(pitch), float(yaw)


def angle_between(R1: ArrayLike, R2: ArrayLike) -> float:
    """Geodesic angle (rad) between two rotations, in [0, pi]."""
    return float(np.linalg.norm(log_so3(np.asarray(R1, dtype=float).T @ np.asarray(R2, dtype=float))))


# --------------------------------------------------------------------------- SE(3)


def as_pose_array(T: ArrayLike) -> F64:
    """View a 4x4 or a stack of 4x4 poses as float ``(n, 4, 4)`` (no validation)."""
    return np.asarray(T, dtype=float).reshape(-1, 4, 4)


def inv(T: ArrayLike) -> F64:
    """Inverse of a rigid transform (R^T, -R^T t), or of each in a stack ``(n, 4, 4)``; cheaper and
    exacter than np.linalg.inv."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    Ti = np.zeros_like(T)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    Ti[..., 3, 3] = 1.0
    return Ti


def transform_points(T: ArrayLike, points: ArrayLike) -> F64:
    """Apply T to an (N, 3) array of points."""
    T = np.asarray(T, dtype=float)
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    return P @ T[:3, :3].T + T[:3, 3]


# --------------------------------------------------------------------------- SO(3) Jacobians
# exp(w + d) = exp(J_l(w) d) exp(w) = exp(w) exp(J_r(w) d) to first order in d; J_r(w) = J_l(-w).
# Each takes w (3,) -> (3, 3) or (n, 3) -> (n, 3, 3). The coefficients are the closed forms, with
# the leading term of their series below a switch angle; these are the formulas exp_se3 and the
# inverse kinematics have always used, so recordings replay bit for bit. Their rounding near the
# switch (about eps / t in J_l's entries) stays below 1e-8 (tests/test_transforms.py).


def _so3_jacobian(w: ArrayLike, coeffs: Callable[[F64], tuple[F64, F64]]) -> F64:
    """``I + a(t) [w]x + b(t) [w]x^2`` with ``(a, b) = coeffs(t)``, ``t = |w|``."""
    W = hat(w)
    w = np.asarray(w, dtype=float).reshape(W.shape[:-1])
    th = np.linalg.norm(w) if w.ndim == 1 else np.linalg.norm(w, axis=-1)
    a, b = coeffs(np.asarray(th))
    return np.eye(3) + np.asarray(a)[..., None, None] * W + np.asarray(b)[..., None, None] * (W @ W)


def _left_coeffs(th: F64) -> tuple[F64, F64]:
    """``(1 - cos t) / t^2`` and ``(t - sin t) / t^3``; 1/2 and 1/6 below 1e-8 rad."""
    if th.ndim == 0:  # one rotation: Python-float powers (numpy's t**3 can differ from pow() by an ulp)
        t = float(th)
        return (0.5, 1.0 / 6.0) if t < 1e-8 else ((1.0 - np.cos(t)) / t**2, (t - np.sin(t)) / t**3)
    small = th < 1e-8
    t = np.where(small, 1.0, th)
    return np.where(small, 0.5, (1.0 - np.cos(t)) / t**2), np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)


def _left_inv_coeffs(th: F64) -> tuple[F64, F64]:
    """``-1/2`` and ``1/t^2 - (1 + cos t) / (2 t sin t)``; -1/2 and 1/12 below 1e-6 rad."""
    if th.ndim == 0:  # one rotation: Python-float arithmetic, as the IK always computed it (bit for bit)
        t = float(th)
        return -0.5, 1.0 / 12.0 if t < 1e-6 else 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t))
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.full_like(th, -0.5, dtype=float), c


def so3_left_jacobian(w: ArrayLike) -> F64:
    """``J_l(w) = I + (1 - cos t)/t^2 [w]x + (t - sin t)/t^3 [w]x^2``."""
    return _so3_jacobian(w, _left_coeffs)


def so3_left_jacobian_inv(w: ArrayLike) -> F64:
    """``J_l(w)^-1 = I - [w]x / 2 + (1/t^2 - (1 + cos t)/(2 t sin t)) [w]x^2``: maps an angular velocity to
    the rate of the rotation vector; ``log(exp(e) exp(w)) = w + J_l^-1(w) e`` to first order."""
    return _so3_jacobian(w, _left_inv_coeffs)


def so3_right_jacobian(w: ArrayLike) -> F64:
    """``J_r(w) = J_l(-w) = J_l(w)^T``."""
    return so3_left_jacobian(-np.asarray(w, dtype=float))


def so3_right_jacobian_inv(w: ArrayLike) -> F64:
    """``J_r(w)^-1 = J_l(-w)^-1``: ``exp(w) exp(d) = exp(w + J_r^-1(w) d)`` to first order."""
    return so3_left_jacobian_inv(-np.asarray(w, dtype=float))


# --------------------------------------------------------------------------- SE(3) exp / log


def exp_se3(xi: ArrayLike) -> F64:
    """Exponential map of a twist xi = (v, w) to a 4x4 transform."""
    xi = np.asarray(xi, dtype=float).reshape(6)
    v, w = xi[:3], xi[3:]
    return T_from_Rt(exp_so3(w), so3_left_jacobian(w) @ v)


def log_se3(T: ArrayLike) -> F64:
    """Logarithm of a 4x4 transform as a twist (v, w)."""
    T = np.asarray(T, dtype=float)
    w = log_so3(T[:3, :3])
    v = np.linalg.solve(so3_left_jacobian(w), T[:3, 3])
    return np.concatenate([v, w])


def adjoint(T: ArrayLike) -> F64:
    """6x6 adjoint of T for twists ordered (v, w): Ad_T xi = log(T exp(xi) T^-1)."""
    T = np.asarray(T, dtype=float)
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[:3, 3:] = hat(t) @ R
    A[3:, 3:] = R
    return A


def pose_error(T_a: ArrayLike, T_b: ArrayLike) -> tuple[float, float]:
    """(translation distance in m, rotation angle in rad) between two poses of the same frame."""
    T_a = np.asarray(T_a, dtype=float)
    T_b = np.asarray(T_b, dtype=float)
    return float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])), angle_between(T_a[:3, :3], T_b[:3, :3])


# --------------------------------------------------------------------------- decoupled perturbation


def retract(T: ArrayLike, delta: ArrayLike) -> F64:
    """Apply decoupled perturbations ``delta = (dt, dphi)`` ``(n, 6)`` to poses ``(n, 4, 4)``."""
    T = as_pose_array(T)
    d = np.asarray(delta, dtype=float).reshape(-1, 6)
    out = T.copy()
    out[:, :3, :3] = exp_so3(d[:, 3:]) @ T[:, :3, :3]
    out[:, :3, 3] = T[:, :3, 3] + d[:, :3]
    return out


def pose_delta(T_meas: ArrayLike, T_model: ArrayLike) -> F64:
    """Decoupled difference ``(t_meas - t_model, log(R_meas R_model^T))`` per pose, ``(n, 6)``.

    It is the ``delta`` with ``retract(T_model, delta) == T_meas``.
    """
    Tm = as_pose_array(T_meas)
    Tp = as_pose_array(T_model)
    dR = Tm[:, :3, :3] @ np.transpose(Tp[:, :3, :3], (0, 2, 1))
    return np.concatenate([Tm[:, :3, 3] - Tp[:, :3, 3], log_so3(dR)], axis=1)


def _block(tl: F64, tr: F64, br: F64) -> F64:
    G = np.zeros((tl.shape[0], 6, 6))
    G[:, :3, :3], G[:, :3, 3:], G[:, 3:, 3:] = tl, tr, br
    return G


def d_product_left(P: ArrayLike, Q: ArrayLike) -> F64:
    """d(P Q) / d(perturbation of P): ``[[I, -[R_P t_Q]x], [0, I]]``, shape ``(n, 6, 6)``."""
    P, Q = np.broadcast_arrays(as_pose_array(P), as_pose_array(Q))
    lever = np.einsum("nij,nj->ni", P[:, :3, :3], Q[:, :3, 3])
    eye = np.broadcast_to(np.eye(3), (P.shape[0], 3, 3))
    return _block(eye, -hat(lever), eye)


def d_product_right(P: ArrayLike) -> F64:
    """d(P Q) / d(perturbation of Q): ``[[R_P, 0], [0, R_P]]``, shape ``(n, 6, 6)``."""
    R = as_pose_array(P)[:, :3, :3]
    return _block(R, np.zeros_like(R), R)


def d_inverse(P: ArrayLike) -> F64:
    """d(P^-1) / d(perturbation of P): ``[[-R^T, -R^T [t]x], [0, -R^T]]``, shape ``(n, 6, 6)``."""
    P = as_pose_array(P)
    Rt = np.transpose(P[:, :3, :3], (0, 2, 1))
    return _block(-Rt, -Rt @ hat(P[:, :3, 3]), -Rt)
