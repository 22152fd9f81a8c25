"""Rigid transforms in SE(3): the one place that fixes vgr's frame and rotation conventions.

Conventions (DESIGN.md, not optional):

* ``T_a_b`` is the pose of frame *b* in frame *a*; it maps points from *b* to *a*:
  ``p_a = T_a_b @ p_b``.  Chains therefore read left to right: ``T_a_c = T_a_b @ T_b_c``.
* Units are metres and radians inside the code.
* Quaternions are ``(x, y, z, w)`` (scipy's order), unit norm, ``w >= 0`` when we produce them.
* Twists / tangent vectors are ``xi = (v, w)``: translation part first, rotation part second,
  with the *left* (world-frame) perturbation ``T' = exp(xi) @ T`` unless a function says otherwise.

Robot-vendor 6-vectors are converted here, each by an explicitly named function, so that an adapter
never guesses: UR ``[x, y, z, rx, ry, rz]`` (m, rotation vector), ABB ``pos_mm + quat(w, x, y, z)``,
KUKA ``X Y Z A B C`` (mm, degrees, ``R = Rz(A) Ry(B) Rx(C)``).

scipy.spatial.transform.Rotation is the rotation library; this module adds only SE(3) glue.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

F64 = NDArray[np.float64]

__all__ = [
    "Rotation",
    "T_from_Rt",
    "T_from_abb",
    "T_from_kuka_abc",
    "T_from_pose7",
    "T_from_rotvec",
    "T_from_ur",
    "abb_from_T",
    "adjoint",
    "angle_between",
    "as_transform",
    "check_rotation",
    "euler_zyx_from_R",
    "exp_se3",
    "exp_so3",
    "hat",
    "inv",
    "is_rotation",
    "kuka_abc_from_T",
    "log_se3",
    "log_so3",
    "orthonormalize",
    "pose7_from_T",
    "pose_error",
    "quat_xyzw_from_R",
    "rotvec_from_R",
    "transform_points",
    "ur_from_T",
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


def as_transform(T: ArrayLike, *, name: str = "transform", tol: float = 1e-6) -> F64:
    """Validate and return a float 4x4 rigid transform; raise ValueError naming *name* otherwise."""
    A = np.asarray(T, dtype=float)
    if A.shape != (4, 4):
        raise ValueError(f"{name} must be 4x4, got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError(f"{name} contains NaN or infinity")
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
    A = np.asarray(R, dtype=float)
    if A.shape != (3, 3):
        raise ValueError(f"{name} must be 3x3, got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError(f"{name} contains NaN or infinity")
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


def hat(w: ArrayLike) -> F64:
    """Skew-symmetric matrix [w]x such that hat(w) @ v = w x v."""
    x, y, z = np.asarray(w, dtype=float).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp_so3(w: ArrayLike) -> F64:
    """Rotation matrix of the rotation vector w."""
    return Rotation.from_rotvec(np.asarray(w, dtype=float).reshape(3)).as_matrix()


def log_so3(R: ArrayLike) -> F64:
    """Rotation vector of R (robust near 0 and pi: scipy goes through the quaternion)."""
    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()


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


def inv(T: ArrayLike) -> F64:
    """Inverse of a rigid transform (R^T, -R^T t), cheaper and exacter than np.linalg.inv."""
    T = np.asarray(T, dtype=float)
    R = T[:3, :3]
    Ti = np.eye(4)
    Ti[:3, :3] = R.T
    Ti[:3, 3] = -R.T @ T[:3, 3]
    return Ti


def transform_points(T: ArrayLike, points: ArrayLike) -> F64:
    """Apply T to an (N, 3) array of points."""
    T = np.asarray(T, dtype=float)
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    return P @ T[:3, :3].T + T[:3, 3]


def _left_jacobian_so3(w: F64) -> F64:
    th = float(np.linalg.norm(w))
    W = hat(w)
    if th < 1e-8:
        return np.eye(3) + 0.5 * W + W @ W / 6.0
    return np.eye(3) + (1.0 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


def exp_se3(xi: ArrayLike) -> F64:
    """Exponential map of a twist xi = (v, w) to a 4x4 transform."""
    xi = np.asarray(xi, dtype=float).reshape(6)
    v, w = xi[:3], xi[3:]
    return T_from_Rt(exp_so3(w), _left_jacobian_so3(w) @ v)


def log_se3(T: ArrayLike) -> F64:
    """Logarithm of a 4x4 transform as a twist (v, w)."""
    T = np.asarray(T, dtype=float)
    w = log_so3(T[:3, :3])
    v = np.linalg.solve(_left_jacobian_so3(w), T[:3, 3])
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


# --------------------------------------------------------------------------- vendor 6-vectors


def T_from_ur(pose: Sequence[float]) -> F64:
    """UR pose ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) -> T_base_tcp."""
    p = np.asarray(pose, dtype=float).reshape(6)
    return T_from_rotvec(p[3:], p[:3])


def ur_from_T(T: ArrayLike) -> F64:
    """T_base_tcp -> UR pose ``[x, y, z, rx, ry, rz]`` (m, rad)."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[:3, 3], log_so3(T[:3, :3])])


def T_from_abb(pos_mm: Sequence[float], quat_wxyz: Sequence[float]) -> F64:
    """ABB robtarget ``trans`` (mm) and ``rot`` quaternion (q1..q4 = w, x, y, z) -> 4x4 in metres."""
    w, x, y, z = np.asarray(quat_wxyz, dtype=float).reshape(4)
    return T_from_pose7(np.asarray(pos_mm, dtype=float) / 1000.0, (x, y, z, w))


def abb_from_T(T: ArrayLike) -> tuple[F64, F64]:
    """4x4 (m) -> ABB ``trans`` (mm) and ``rot`` (w, x, y, z) with w >= 0."""
    p, q = pose7_from_T(T)
    return p * 1000.0, np.array([q[3], q[0], q[1], q[2]])


def T_from_kuka_abc(xyzabc: Sequence[float]) -> F64:
    """KUKA ``X Y Z A B C`` (mm, degrees; R = Rz(A) Ry(B) Rx(C)) -> 4x4 in metres."""
    x, y, z, a, b, c = np.asarray(xyzabc, dtype=float).reshape(6)
    R = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()
    return T_from_Rt(R, np.array([x, y, z]) / 1000.0)


def kuka_abc_from_T(T: ArrayLike) -> F64:
    """4x4 (m) -> KUKA ``X Y Z A B C`` (mm, degrees)."""
    T = np.asarray(T, dtype=float)
    a, b, c = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    return np.concatenate([T[:3, 3] * 1000.0, [a, b, c]])
