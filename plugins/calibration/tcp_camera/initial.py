"""Closed-form estimates of T_cam_base and p_flange_tcp.

``seed002_closed_form`` is seed 002's two-step method:

1. *pure translations* (flange orientation unchanged) give ``p_cam_i - p_cam_j =
   R_cam_base (t_base_flange_i - t_base_flange_j)``; the rotation is the Wahba/Kabsch fit of the
   centred camera points onto the centred flange positions of each translation group
   (scipy ``Rotation.align_vectors``; needs translations along >= 2 non-parallel directions);
2. *orientation changes* then give ``R_cam_base^T p_cam_i - t_base_flange_i = R_base_flange_i
   p_flange_tcp + R_cam_base^T t_cam_base``, linear in ``(p_flange_tcp, t_cam_base)`` — the seed's
   pairwise differences ``A X = B`` solved jointly for all samples (no double use of a sample).

``general_linear`` needs no pure translations: writing ``R_cam_base R_i p = G vec(R_i)`` with the
3x9 unknown ``G = R_cam_base (I kron p^T)`` makes the model linear in ``(G, R_cam_base, t_cam_base)``
(13 unknowns per camera axis); ``R_cam_base`` is then projected onto SO(3) and step 2 above gives
``p`` and ``t_cam_base``. Needs >= 13 samples with varied orientations.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, orthonormalize
from plugins.calibration.tcp_camera.data import TcpCameraData

F64 = NDArray[np.float64]


@dataclass
class ClosedForm:
    T_cam_base: F64
    p_flange_tcp: F64
    method: str
    translation_groups: list[NDArray[np.int_]]


def translation_groups(data: TcpCameraData, tol_rad: float) -> list[NDArray[np.int_]]:
    """Groups (>= 2 samples) of samples with the same flange orientation within *tol_rad*."""
    rots = Rotation.from_matrix(data.T_base_flange[:, :3, :3])
    unassigned = list(range(data.n))
    groups = []
    while unassigned:
        i = unassigned.pop(0)
        d = (rots[i].inv() * rots[unassigned]).magnitude() if unassigned else np.zeros(0)
        members = [i] + [j for j, dj in zip(unassigned, d, strict=True) if dj < tol_rad]
        unassigned = [j for j in unassigned if j not in members]
        if len(members) >= 2:
            groups.append(np.array(members))
    return groups


def translation_span(data: TcpCameraData, groups: list[NDArray[np.int_]]) -> F64:
    """Singular values (m) of the centred flange positions stacked over the translation groups."""
    if not groups:
        return np.zeros(3)
    t = data.T_base_flange[:, :3, 3]
    stacked = np.vstack([t[g] - t[g].mean(axis=0) for g in groups])
    s = np.linalg.svd(stacked, compute_uv=False)
    return np.pad(s, (0, 3 - s.size))


def _rotation_from_translations(data: TcpCameraData, groups: list[NDArray[np.int_]]) -> F64:
    t = data.T_base_flange[:, :3, 3]
    a = np.vstack([data.p_cam[g] - data.p_cam[g].mean(axis=0) for g in groups])
    b = np.vstack([t[g] - t[g].mean(axis=0) for g in groups])
    with warnings.catch_warnings():  # collinear input: reported by the solver's identifiability check
        warnings.simplefilter("ignore", UserWarning)
        rot, _ = Rotation.align_vectors(a, b)
    return rot.as_matrix()


def _tcp_given_rotation(data: TcpCameraData, R_cb: F64) -> tuple[F64, F64]:
    """Linear LS for (p_flange_tcp, t_cam_base) given R_cam_base."""
    n = data.n
    A = np.zeros((3 * n, 6))
    y = np.zeros(3 * n)
    for i in range(n):
        A[3 * i : 3 * i + 3, :3] = data.T_base_flange[i, :3, :3]
        A[3 * i : 3 * i + 3, 3:] = np.eye(3)
        y[3 * i : 3 * i + 3] = R_cb.T @ data.p_cam[i] - data.T_base_flange[i, :3, 3]
    sol, *_ = np.linalg.lstsq(A, y, rcond=1e-9)
    return sol[:3], R_cb @ sol[3:]


#: the method name of :func:`seed002_closed_form` in results (docs/vive_and_tcp.md explains it)
TRANSLATIONS_METHOD = "closed form: pure translations + linear LS (docs/vive_and_tcp.md)"


def seed002_closed_form(data: TcpCameraData, groups: list[NDArray[np.int_]]) -> ClosedForm:
    """Seed 002's method (module docstring); *groups* from :func:`translation_groups`."""
    R_cb = _rotation_from_translations(data, groups)
    p, t_cb = _tcp_given_rotation(data, R_cb)
    return ClosedForm(T_from_Rt(R_cb, t_cb), p, TRANSLATIONS_METHOD, groups)


def general_linear(data: TcpCameraData) -> ClosedForm:
    """Closed form without pure translations (module docstring). Raises ValueError if ill-posed."""
    n = data.n
    if n < 13:
        raise ValueError(
            f"no pure-translation set and only {n} samples: the general linear start needs >= 13; "
            "add >= 3 pure translations (same flange orientation) along 2+ directions (seed 002)"
        )
    R = data.T_base_flange[:, :3, :3]
    t = data.T_base_flange[:, :3, 3]
    A = np.hstack([R.reshape(n, 9), t, np.ones((n, 1))])
    s = np.linalg.svd(A, compute_uv=False)
    if s[-1] < 1e-6 * s[0]:
        raise ValueError(
            "orientations/positions too similar for the general linear start (rank deficient); "
            "add pure translations along 2+ directions and rotations about 2+ axes"
        )
    X, *_ = np.linalg.lstsq(A, data.p_cam, rcond=None)  # rows: vec(G) (9), R_cam_base (3), t (1)
    R_cb = orthonormalize(X[9:12].T)
    p, t_cb = _tcp_given_rotation(data, R_cb)
    return ClosedForm(T_from_Rt(R_cb, t_cb), p, "general linear closed form (no pure translations)", [])
