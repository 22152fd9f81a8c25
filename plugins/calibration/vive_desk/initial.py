"""Initial estimates of T_base_desktop and T_tracker_tcp (seed 001, step 1, and its exact form).

``seed_step1_T_base_desktop`` is the seed's step 1 verbatim: origin = mean tracker position,
z = mean tracker z axis, x = tracker_2 - tracker_1 projected on the plane, y = z x x. It assumes
that the tracker's z axis is the desk normal and that P1 -> P2 is the desk's x axis (the seed's own
layout puts P2 on -y, so its x axis is 90 deg off) and it ignores the lever arm; the seed's
optimiser starts T_tracker_tcp at the identity.

``initial_estimate`` keeps the seed's idea (the tracker positions are the desk's contact points
carried by one rigid offset) but solves it exactly: the desk rotation is the Kabsch/Wahba fit of the
tracker-position cloud onto the desk TCP positions (scipy ``Rotation.align_vectors``), the
tracker-to-TCP rotation the chordal mean of ``R_tracker_tcp_i = R_base_tracker_i^T R_base_desktop
R_desktop_tcp_i``, and the two translations a linear least-squares solve of
``t_base_desktop - R_base_tracker_i t_tracker_tcp = t_base_tracker_i - R_base_desktop q_i``. When
that system is rank deficient (one fixture orientation: the lever arm is not identifiable) the
translation of T_tracker_tcp is taken from the prior, or zero, along the missing directions.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt
from plugins.calibration.vive_desk.checks import distinct_points, orientation_groups
from plugins.calibration.vive_desk.data import TrackerTcpPrior, ViveDeskData

F64 = NDArray[np.float64]


def seed_step1_T_base_desktop(T_base_tracker: F64) -> F64:
    """Seed 001 step 1, literally (uses the first two samples for the x axis)."""
    t = T_base_tracker[:, :3, 3]
    centre = t.mean(axis=0)
    z = T_base_tracker[:, :3, 2].mean(axis=0)
    z = z / np.linalg.norm(z)
    x = t[1] - t[0]
    x = x - np.dot(x, z) * z
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return T_from_Rt(np.column_stack([x, y, z]), centre)


def _rotation_group(data: ViveDeskData) -> NDArray[np.int_]:
    """Samples for the Kabsch step: the fixture group with the widest non-collinear point layout."""
    best, best_width = np.arange(data.n), -1.0
    for g in orientation_groups(data):
        pts, _ = distinct_points(data.tcp_positions_desktop[g])
        if len(pts) < 3:
            continue
        width = float(np.linalg.svd(pts - pts.mean(0), compute_uv=False)[1])
        if width > best_width:
            best, best_width = g, width
    return best


def initial_estimate(data: ViveDeskData, prior: TrackerTcpPrior | None = None) -> tuple[F64, F64]:
    """(T_base_desktop, T_tracker_tcp) from the closed-form steps described in the module doc."""
    g = _rotation_group(data)
    q = data.tcp_positions_desktop
    t = data.T_base_tracker[:, :3, 3]
    a = t[g] - t[g].mean(axis=0)
    b = q[g] - q[g].mean(axis=0)
    with warnings.catch_warnings():  # collinear input: reported by the solver's identifiability check
        warnings.simplefilter("ignore", UserWarning)
        rot, _ = Rotation.align_vectors(a, b)  # a ~ R b
    R_BD = rot.as_matrix()
    known = np.flatnonzero(data.orientation_known)
    if known.size:
        R_KC_i = np.einsum("nji,jk,nkl->nil", data.T_base_tracker[known, :3, :3], R_BD, data.R_desktop_tcp[known])
        R_KC = Rotation.from_matrix(R_KC_i).mean().as_matrix()
    else:
        R_KC = np.eye(3) if prior is None else prior.T_tracker_tcp[:3, :3]
    # translations: t_BD - R_BK_i t_KC = y_i with y_i = t_BK_i - R_BD q_i. Eliminating t_BD (means)
    # leaves -(R_BK_i - mean R_BK) t_KC = y_i - mean y, solved by a pseudo-inverse that ignores
    # directions about which the tool turned by less than ~3 deg (not determined: keep the prior/0)
    R_BK = data.T_base_tracker[:, :3, :3]
    y = t - q @ R_BD.T
    A = -(R_BK - R_BK.mean(axis=0)).reshape(-1, 3)
    t_KC = np.zeros(3) if prior is None else prior.T_tracker_tcp[:3, 3].copy()
    rhs = (y - y.mean(axis=0)).reshape(-1) - A @ t_KC
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    keep = s > 0.05 * np.sqrt(data.n)
    t_KC = t_KC + Vt[keep].T @ ((U[:, keep].T @ rhs) / s[keep])
    t_BD = np.mean(y + R_BK @ t_KC, axis=0)
    return T_from_Rt(R_BD, t_BD), T_from_Rt(R_KC, t_KC)
