"""Simulated TCP-by-camera data with known ground truth (seed 002's procedure).

Poses: ``n_translations`` pure translations of the flange at one orientation (a non-collinear
pattern, for the camera-to-base rotation) and ``n_rotations`` orientation changes about random
axes (or about one given axis, the degenerate case) up to ``max_rotation_deg``, all around
``centre``. Camera noise is Gaussian per camera axis; robot noise optional. Seeded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, exp_so3, inv
from plugins.calibration.tcp_camera.data import TcpCameraData, TcpNoiseModel

F64 = NDArray[np.float64]


def true_T_base_cam() -> F64:
    """A camera 1.3 m from the robot, looking back at the working area."""
    R = Rotation.from_euler("xyz", [-150.0, 5.0, 95.0], degrees=True).as_matrix()
    return T_from_Rt(R, [1.3, 0.1, 0.9])


TRUE_P_FLANGE_TCP = np.array([0.012, -0.008, 0.185])


@dataclass
class SimulatedTcp:
    data: TcpCameraData
    T_cam_base: F64
    p_flange_tcp: F64


def simulate_tcp_camera(
    *,
    seed: int,
    n_translations: int = 6,
    n_rotations: int = 10,
    max_rotation_deg: float = 30.0,
    rotation_axis: ArrayLike | None = None,
    camera_sigma_m: float | tuple[float, float, float] = 0.3e-3,
    robot_position_sigma_m: float = 0.0,
    robot_rotation_sigma_rad: float = 0.0,
    T_base_cam: ArrayLike | None = None,
    p_flange_tcp: ArrayLike | None = None,
    centre: ArrayLike = (0.5, 0.0, 0.35),
    translation_step_m: float = 0.08,
) -> SimulatedTcp:
    rng = np.random.default_rng(seed)
    T_BC = true_T_base_cam() if T_base_cam is None else np.asarray(T_base_cam, dtype=float)
    T_CB = inv(T_BC)
    pF = TRUE_P_FLANGE_TCP if p_flange_tcp is None else np.asarray(p_flange_tcp, dtype=float)
    R0 = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()  # tool pointing down
    c = np.asarray(centre, dtype=float)
    poses = []
    pattern = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [-1, 0, 1], [0, -1, -1], [1, -1, 1]],
        dtype=float,
    )
    for k in range(n_translations):
        step = pattern[k % len(pattern)] * translation_step_m * (1 + k // len(pattern))
        poses.append(T_from_Rt(R0, c + step))
    for _ in range(n_rotations):
        if rotation_axis is None:
            axis = rng.normal(size=3)
        else:
            axis = np.asarray(rotation_axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        ang = np.radians(rng.uniform(-max_rotation_deg, max_rotation_deg))
        R = exp_so3(axis * ang) @ R0
        poses.append(T_from_Rt(R, c + rng.uniform(-0.05, 0.05, size=3)))
    T_true = np.array(poses)
    sig_c = np.broadcast_to(np.asarray(camera_sigma_m, dtype=float), (3,))
    p_cam = np.array([(T_CB @ T @ np.append(pF, 1.0))[:3] for T in T_true])
    p_cam = p_cam + rng.normal(size=p_cam.shape) * sig_c
    T_meas = T_true.copy()
    if robot_position_sigma_m or robot_rotation_sigma_rad:
        for i in range(len(T_meas)):
            T_meas[i, :3, :3] = T_true[i, :3, :3] @ exp_so3(rng.normal(scale=robot_rotation_sigma_rad, size=3))
            T_meas[i, :3, 3] += rng.normal(scale=robot_position_sigma_m, size=3)
    noise = TcpNoiseModel(tuple(sig_c), robot_position_sigma_m, robot_rotation_sigma_rad)
    return SimulatedTcp(TcpCameraData.from_arrays(T_meas, p_cam, noise=noise), T_CB, pF)
