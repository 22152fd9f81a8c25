"""Simulated Vive desk calibration data with known ground truth (tests, benchmarks, docs).

The simulation follows the model of :mod:`plugins.calibration.vive_desk.model`: the fixture puts the
TCP at ``q_i`` with its nominal orientation scattered by a random rotation about the TCP
(``fixture_scatter_rad`` per axis), the contact point may be misplaced (``desk_point_sigma_m``) and
the tracker reports its pose with position jitter (base frame) and rotation jitter (tracker frame).
Every random draw comes from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_rotvec, T_from_Rt, exp_so3, inv
from plugins.calibration.vive_desk.data import ViveDeskData, ViveNoiseModel

F64 = NDArray[np.float64]

#: seed 001's layout: P1 origin, P2 20 cm to the right (-y), P3 20 cm forward (+x)
SEED_POINTS_3 = np.array([[0.0, 0.0, 0.0], [0.0, -0.2, 0.0], [0.2, 0.0, 0.0]])
#: seed 001 scheme B: the square
SEED_POINTS_4 = np.vstack([SEED_POINTS_3, [[0.2, -0.2, 0.0]]])
#: the square plus its centre
SEED_POINTS_5 = np.vstack([SEED_POINTS_4, [[0.1, -0.1, 0.0]]])


def true_T_base_desktop() -> F64:
    """A plausible lighthouse-to-desk pose: OpenVR frames are y-up, the desk is 1.5 m below and
    about 2 m in front of the base station, slightly tilted and yawed."""
    R = Rotation.from_euler("xyz", [-90.0, 25.0, 1.5], degrees=True).as_matrix()
    return T_from_Rt(R, [0.9, -1.4, -2.1])


def true_T_tracker_tcp() -> F64:
    """Tracker on top of the gripper, tilted; lever arm 0.155 m (seed 001 assumes L = 0.15 m)."""
    return T_from_rotvec(np.radians([170.0, 12.0, -35.0]), [0.03, -0.02, 0.15])


def tilted_fixture_orientations(tilt_deg: float = 30.0) -> F64:
    """Three fixture orientations for a fully identifiable design: upright, tilted about desk x,
    tilted about desk y (relative rotations about two different axes)."""
    return np.stack(
        [
            np.eye(3),
            Rotation.from_euler("x", tilt_deg, degrees=True).as_matrix(),
            Rotation.from_euler("y", tilt_deg, degrees=True).as_matrix(),
        ]
    )


@dataclass
class SimulatedContacts:
    data: ViveDeskData
    T_base_desktop: F64
    T_tracker_tcp: F64
    scatter_rotvec: F64  # (N, 3) true fixture scatter, TCP frame
    T_base_tracker_true: F64  # (N, 4, 4) noise-free tracker poses


def simulate_contacts(
    desk_points: ArrayLike,
    *,
    seed: int,
    T_base_desktop: ArrayLike | None = None,
    T_tracker_tcp: ArrayLike | None = None,
    R_desktop_tcp: ArrayLike | None = None,
    contact_offset_z: float = 0.12,
    tracker_position_sigma_m: float = 0.5e-3,
    tracker_rotation_sigma_rad: float = float(np.radians(0.1)),
    fixture_scatter_rad: float = float(np.radians(0.3)),
    desk_point_sigma_m: float = 0.0,
    orientation_known: ArrayLike | None = None,
    noise_model: ViveNoiseModel | None = None,
) -> SimulatedContacts:
    """Contacts at *desk_points* (N, 3) with the fixture orientation(s) *R_desktop_tcp* (3x3 or N).

    The returned data carry *noise_model* (default: the generating noise, i.e. a correct model).
    """
    rng = np.random.default_rng(seed)
    P = np.asarray(desk_points, dtype=float).reshape(-1, 3)
    n = len(P)
    T_BD = true_T_base_desktop() if T_base_desktop is None else np.asarray(T_base_desktop, dtype=float)
    T_KC = true_T_tracker_tcp() if T_tracker_tcp is None else np.asarray(T_tracker_tcp, dtype=float)
    R_fix = np.eye(3) if R_desktop_tcp is None else np.asarray(R_desktop_tcp, dtype=float)
    if R_fix.shape == (3, 3):
        R_fix = np.tile(R_fix, (n, 1, 1))
    offsets = np.tile([0.0, 0.0, contact_offset_z], (n, 1))
    scatter = rng.normal(scale=fixture_scatter_rad, size=(n, 3))
    point_err = rng.normal(scale=desk_point_sigma_m, size=(n, 3))
    T_true = np.empty((n, 4, 4))
    T_meas = np.empty((n, 4, 4))
    for i in range(n):
        T_DC = T_from_Rt(R_fix[i] @ exp_so3(scatter[i]), P[i] + offsets[i] + point_err[i])
        T_true[i] = T_BD @ T_DC @ inv(T_KC)
        R = T_true[i, :3, :3] @ exp_so3(rng.normal(scale=tracker_rotation_sigma_rad, size=3))
        t = T_true[i, :3, 3] + rng.normal(scale=tracker_position_sigma_m, size=3)
        T_meas[i] = T_from_Rt(R, t)
    noise = noise_model or ViveNoiseModel(
        tracker_position_sigma_m=tracker_position_sigma_m,
        tracker_rotation_sigma_rad=tracker_rotation_sigma_rad,
        fixture_rotation_sigma_rad=fixture_scatter_rad,
        desk_point_sigma_m=desk_point_sigma_m,
    )
    data = ViveDeskData.from_contacts(
        P,
        T_meas,
        tcp_offsets_desktop=offsets,
        R_desktop_tcp=R_fix,
        orientation_known=orientation_known,
        noise=noise,
    )
    return SimulatedContacts(data, T_BD, T_KC, scatter, T_true)
