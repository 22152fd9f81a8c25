"""Closed-form hand-eye initialisers: Tsai-Lenz, Park-Martin, Daniilidis (AX=XB) and Shah (AX=ZB).

Written from the papers with numpy/scipy, in vgr's ``A_i X B_i = Y`` form (see ``problem``):

* Tsai & Lenz 1989: linear least squares on the modified Rodrigues (Gibbs) vector of X, then
  ``(R_Aij - I) t_X = R_X t_Bij - t_Aij``.
* Park & Martin 1994: ``log(R_Aij) = R_X log(R_Bij)``, solved as orthogonal Procrustes
  (``Rotation.align_vectors``, i.e. Kabsch with the determinant fixed), then the same translation.
* Daniilidis 1999: the 6 x 8 dual-quaternion system per motion, its 2-D null space and the two
  unit-norm / orthogonality constraints.
* Shah 2013 (robot-world AX = ZB): the leading singular pair of ``sum_i R_Bi^T (x) R_Ai`` gives
  ``vec(R_X)`` and ``vec(R_Y)`` jointly, then one linear least squares for both translations.

Pitfalls that made OpenCV's versions fail on valid data (opencv/opencv#24871), handled here:

* q / -q: a motion pair only satisfies the quaternion equations when the robot and camera
  quaternions carry the same sign. Quaternions are taken with ``w >= 0``; when ``w`` is near 0
  (relative rotation near 180 degrees) the sign is not decided by ``w`` but by consistency with a
  first-pass estimate from the unambiguous pairs (``q_A . R_X q_B > 0``). Rotation vectors near
  pi (Park-Martin) get the same treatment with the equivalent vector of length ``2 pi - theta``.
* near-0 relative rotations carry no information about X and only add noise: pairs below
  ``min_pair_angle`` are left out (when enough others remain).
* X near 180 degrees: the Gibbs vector of Tsai-Lenz diverges there. A first pass solves Tsai's
  equation multiplied by ``cos(theta_X / 2)`` (homogeneous, valid at any angle); the Tsai-Lenz
  least squares proper then solves for ``X R1^T`` (near the identity) and composes back.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, hat, inv, orthonormalize
from plugins.calibration.handeye.problem import RelativeMotions, Setup, relative_motions, robot_A

F64 = NDArray[np.float64]

AxxbMethod = Literal["tsai_lenz", "park_martin", "daniilidis"]
AXXB_METHODS: tuple[AxxbMethod, ...] = ("tsai_lenz", "park_martin", "daniilidis")
CLOSED_FORM_METHODS: tuple[str, ...] = (*AXXB_METHODS, "shah")

#: quaternion scalar part below which the q / -q choice of a motion is treated as ambiguous
#: (|w| < 0.15 <=> relative rotation above about 163 degrees)
AMBIGUOUS_W = 0.15

__all__ = [
    "AXXB_METHODS",
    "CLOSED_FORM_METHODS",
    "closed_form",
    "complete_y",
    "daniilidis",
    "park_martin",
    "shah",
    "tsai_lenz",
]


# --------------------------------------------------------------------------- shared pieces


def _select_pairs(m: RelativeMotions, min_pair_angle: float) -> RelativeMotions:
    ang = np.linalg.norm(Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec(), axis=1)
    keep = ang >= min_pair_angle
    if np.count_nonzero(keep) < 2:  # keep whatever there is; the degeneracy check speaks about it
        return m
    return RelativeMotions(m.A[keep], m.B[keep], m.pairs[keep])


def _quats_w_positive(R: F64) -> F64:
    """Quaternions (x, y, z, w) with w >= 0."""
    q = Rotation.from_matrix(R).as_quat()
    q[q[:, 3] < 0] *= -1.0
    return q


def _aligned_quaternions(m: RelativeMotions, R_hint: F64 | None) -> tuple[F64, F64, NDArray[np.bool_]]:
    """Robot and camera motion quaternions with consistent signs, and which pairs are usable.

    Without a hint, pairs whose sign is ambiguous (|w| small) are marked unusable; with the hint
    every pair is usable and the camera quaternion is flipped to agree with ``R_hint``.
    """
    qa = _quats_w_positive(m.A[:, :3, :3])
    qb = _quats_w_positive(m.B[:, :3, :3])
    ambiguous = np.minimum(qa[:, 3], qb[:, 3]) < AMBIGUOUS_W
    if R_hint is None:
        return qa, qb, ~ambiguous
    agree = np.einsum("ki,ki->k", qa[:, :3], qb[:, :3] @ R_hint.T)
    flip = ambiguous & (agree < 0)
    qb[flip] *= -1.0
    return qa, qb, np.ones(len(qa), dtype=bool)


def _usable_or_all(usable: NDArray[np.bool_]) -> NDArray[np.bool_]:
    return usable if np.count_nonzero(usable) >= 2 else np.ones_like(usable)


def _translation_ls(m: RelativeMotions, R_X: F64) -> F64:
    """Least squares ``(R_Aij - I) t_X = R_X t_Bij - t_Aij`` over all pairs."""
    lhs = (m.A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (m.B[:, :3, 3] @ R_X.T - m.A[:, :3, 3]).reshape(-1)
    t, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return np.asarray(t, dtype=float)


def _conjugate_camera(m: RelativeMotions, R: F64) -> RelativeMotions:
    """Motions for the unknown ``X' = X H^-1`` with ``H = (R, 0)``: ``B' = H B H^-1``."""
    H = T_from_Rt(R, np.zeros(3))
    return RelativeMotions(m.A, H @ m.B @ inv(H), m.pairs)


# --------------------------------------------------------------------------- Tsai-Lenz


def _tsai_rotation(m: RelativeMotions, R_hint: F64 | None) -> F64:
    qa, qb, usable = _aligned_quaternions(m, R_hint)
    use = _usable_or_all(usable)
    Pa, Pb = 2.0 * qa[use, :3], 2.0 * qb[use, :3]  # modified Rodrigues vectors 2 sin(theta/2) axis
    lhs = hat(Pa + Pb).reshape(-1, 3)
    rhs = (Pb - Pa).reshape(-1)
    gibbs, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)  # tan(theta_X / 2) * axis_X
    q = np.append(gibbs, 1.0) / np.sqrt(1.0 + gibbs @ gibbs)
    return Rotation.from_quat(q).as_matrix()


def _tsai_rotation_homogeneous(m: RelativeMotions) -> F64:
    """Tsai's equation multiplied by cos(theta_X / 2): ``w (a - b) + [a + b]x v = 0``, valid at any angle."""
    qa, qb, usable = _aligned_quaternions(m, None)
    use = _usable_or_all(usable)
    a, b = qa[use, :3], qb[use, :3]
    S = np.zeros((len(a), 3, 4))
    S[:, :, :3] = hat(a + b)
    S[:, :, 3] = a - b
    _, _, Vt = np.linalg.svd(S.reshape(-1, 4), full_matrices=False)
    return Rotation.from_quat(Vt[-1]).as_matrix()


def tsai_lenz(m: RelativeMotions, *, min_pair_angle: float = np.deg2rad(0.5)) -> F64:
    """Tsai & Lenz 1989 on relative motions; returns X (4x4)."""
    m = _select_pairs(m, min_pair_angle)
    R1 = _tsai_rotation_homogeneous(m)
    # second pass: unknown X R1^T is near identity (no Gibbs blow-up), all signs resolved with R1
    R_rel = _tsai_rotation(_conjugate_camera(m, R1), np.eye(3))
    R_X = R_rel @ R1
    return T_from_Rt(R_X, _translation_ls(m, R_X))


# --------------------------------------------------------------------------- Park-Martin


def _park_rotation(m: RelativeMotions, R_hint: F64 | None) -> F64:
    alpha = Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec()
    beta = Rotation.from_matrix(m.B[:, :3, :3]).as_rotvec()
    th_a, th_b = np.linalg.norm(alpha, axis=1), np.linalg.norm(beta, axis=1)
    ambiguous = np.maximum(th_a, th_b) > 2.0 * np.arccos(AMBIGUOUS_W)
    if R_hint is None:
        use = _usable_or_all(~ambiguous)
        alpha, beta = alpha[use], beta[use]
    else:
        flip = ambiguous & (np.einsum("ki,ki->k", alpha, beta @ R_hint.T) < 0) & (th_b > 0)
        # the same rotation, written with the opposite axis: (theta - 2 pi) * axis
        beta[flip] *= (1.0 - 2.0 * np.pi / th_b[flip])[:, None]
    rot, _ = Rotation.align_vectors(alpha, beta)  # alpha ~ R_X beta
    return rot.as_matrix()


def park_martin(m: RelativeMotions, *, min_pair_angle: float = np.deg2rad(0.5)) -> F64:
    """Park & Martin 1994 on relative motions; returns X (4x4)."""
    m = _select_pairs(m, min_pair_angle)
    R1 = _park_rotation(m, None)
    R_X = _park_rotation(m, R1)
    return T_from_Rt(R_X, _translation_ls(m, R_X))


# --------------------------------------------------------------------------- Daniilidis


def _dual_quaternions(T: F64, q: F64) -> F64:
    """Dual parts ``q' = 0.5 t q`` (x, y, z, w order) for the real parts ``q`` of poses ``T``."""
    t = T[:, :3, 3]
    # quaternion product (t, 0) * (v, w) = (w t + t x v, -t . v)
    v, w = q[:, :3], q[:, 3]
    vec = w[:, None] * t + np.cross(t, v)
    sca = -np.einsum("ki,ki->k", t, v)
    return 0.5 * np.concatenate([vec, sca[:, None]], axis=1)


def _daniilidis_solve(m: RelativeMotions, R_hint: F64 | None) -> F64:
    qa, qb, usable = _aligned_quaternions(m, R_hint)
    use = _usable_or_all(usable)
    A, B, qa, qb = m.A[use], m.B[use], qa[use], qb[use]
    da, db = _dual_quaternions(A, qa), _dual_quaternions(B, qb)
    a, b, a_, b_ = qa[:, :3], qb[:, :3], da[:, :3], db[:, :3]
    k = len(a)
    # unknown ordered (w, v, w', v') of the dual quaternion of X
    S = np.zeros((k, 6, 8))
    S[:, :3, 0] = a - b
    S[:, :3, 1:4] = hat(a + b)
    S[:, 3:, 0] = a_ - b_
    S[:, 3:, 1:4] = hat(a_ + b_)
    S[:, 3:, 4] = a - b
    S[:, 3:, 5:8] = hat(a + b)
    _, _, Vt = np.linalg.svd(S.reshape(-1, 8), full_matrices=False)
    u, v = Vt[-2], Vt[-1]
    u1, v1, u2, v2 = u[:4], u[4:], v[:4], v[4:]
    # x = l1 u + l2 v with |q| = 1 and q . q' = 0: the second is a quadratic form in (l1, l2)
    Q = np.array([[u1 @ v1, 0.5 * (u1 @ v2 + u2 @ v1)], [0.5 * (u1 @ v2 + u2 @ v1), u2 @ v2]])
    N = np.array([[u1 @ u1, u1 @ u2], [u1 @ u2, u2 @ u2]])
    mu, E = np.linalg.eigh(Q)
    if mu[0] < 0.0 < mu[1]:
        cands = [np.sqrt(mu[1]) * E[:, 0] + s * np.sqrt(-mu[0]) * E[:, 1] for s in (1.0, -1.0)]
    else:  # noise made the form definite: take its direction closest to isotropic
        cands = [E[:, int(np.argmin(np.abs(mu)))]]
    lam = max(cands, key=lambda c: float(c @ N @ c) / float(c @ c))
    lam = lam / np.sqrt(lam @ N @ lam)
    x = lam[0] * u + lam[1] * v
    q = np.array([x[1], x[2], x[3], x[0]])  # -> (x, y, z, w)
    qd = np.array([x[5], x[6], x[7], x[4]])
    R = Rotation.from_quat(q).as_matrix()
    # t = 2 q' q^*: vector part of (qd_v, qd_w) * (-q_v, q_w)
    qv, qw, dv, dw = q[:3], q[3], qd[:3], qd[3]
    t = 2.0 * (dw * (-qv) + qw * dv + np.cross(dv, -qv))
    return T_from_Rt(R, t)


def daniilidis(m: RelativeMotions, *, min_pair_angle: float = np.deg2rad(0.5)) -> F64:
    """Daniilidis 1999 (dual quaternions) on relative motions; returns X (4x4)."""
    m = _select_pairs(m, min_pair_angle)
    X1 = _daniilidis_solve(m, None)
    return _daniilidis_solve(m, X1[:3, :3])


# --------------------------------------------------------------------------- AX = ZB and Y


def shah(A: F64, B: F64) -> tuple[F64, F64]:
    """Shah 2013 Kronecker closed form for ``A_i X B_i = Y`` (absolute poses); returns (X, Y)."""
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    # vec(R_A R_X R_B) = (R_B^T kron R_A) vec(R_X), column-major vec
    K = np.einsum("nji,nkl->nikjl", RB, RA).reshape(len(A), 9, 9).sum(axis=0)
    U, _, Vt = np.linalg.svd(K)
    Rx = Vt[0].reshape(3, 3, order="F")
    Ry = U[:, 0].reshape(3, 3, order="F")
    if np.linalg.det(Rx) < 0:
        Rx, Ry = -Rx, -Ry
    R_X, R_Y = orthonormalize(Rx), orthonormalize(Ry)
    # translations: R_A t_X - t_Y = -(R_A R_X t_B + t_A)
    n = len(A)
    lhs = np.zeros((n, 3, 6))
    lhs[:, :, :3] = RA
    lhs[:, :, 3:] = -np.eye(3)
    rhs = -(np.einsum("nij,nj->ni", RA, B[:, :3, 3] @ R_X.T) + A[:, :3, 3])
    sol, *_ = np.linalg.lstsq(lhs.reshape(-1, 6), rhs.reshape(-1), rcond=None)
    return T_from_Rt(R_X, sol[:3]), T_from_Rt(R_Y, sol[3:])


def complete_y(A: F64, B: F64, X: F64) -> F64:
    """Y from X: the mean of the pose chains ``A_i X B_i`` (chordal rotation mean, mean translation)."""
    chains = A @ X @ B
    R = Rotation.from_matrix(chains[:, :3, :3]).mean().as_matrix()
    return T_from_Rt(R, chains[:, :3, 3].mean(axis=0))


def closed_form(
    setup: Setup,
    T_base_tcp: F64,
    T_cam_target: F64,
    method: str,
    *,
    min_pair_angle: float = np.deg2rad(0.5),
) -> tuple[F64, F64]:
    """(X, Y) of one closed-form method for the set-up (see ``problem``); no validation here."""
    A = robot_A(setup, T_base_tcp)
    if method == "shah":
        return shah(A, T_cam_target)
    solvers = {"tsai_lenz": tsai_lenz, "park_martin": park_martin, "daniilidis": daniilidis}
    if method not in solvers:
        raise ValueError(f"unknown closed-form method {method!r}; use one of {list(CLOSED_FORM_METHODS)}")
    X = solvers[method](relative_motions(setup, T_base_tcp, T_cam_target), min_pair_angle=min_pair_angle)
    return X, complete_y(A, T_cam_target, X)
