"""Simulated hand-eye data sets with known truth (tests, benchmarks, documentation examples).

* :func:`viewing_scene` - a realistic cell: the camera sees the target from 0.35-0.7 m within its
  field of view, tilted up to ``max_tilt_deg`` and rolled about the optical axis; the robot poses
  follow from the chain, for either set-up.
* :func:`opencv_protocol` - the pose generator of OpenCV's own test
  (modules/calib3d/test/test_calibration_hand_eye.cpp, ``simulateData``), re-implemented from its
  description: random-sign rotation vectors with *unnormalised* uniform axes, uniform translations
  with random signs, camera noise added to the rotation vector (0.002 rad) and to the translation
  (5 mm) of T_cam_target. In OpenCV's file the robot noise (0.001 rad, 1 mm) is written into a local
  copy of the gripper pose that is never returned, so its test effectively runs with exact robot
  poses; ``apply_robot_noise=True`` applies it as the protocol describes.
* :func:`add_noise` - the noise model of ``noise`` (decoupled, parent frame).
* :func:`depth_covariances` - per-view camera covariances of a depth camera or PnP: largest along
  each view's line of sight, growing with the distance, translation across the line of sight
  correlated with the tilt; :func:`perturb_poses_cov` draws poses with them.

Every function takes a ``numpy.random.Generator``; nothing reads global random state.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_rotvec, T_from_Rt, inv, retract
from plugins.calibration.handeye.noise import NoiseModel, PoseNoise
from plugins.calibration.handeye.problem import Setup

F64 = NDArray[np.float64]

__all__ = [
    "Scene",
    "add_noise",
    "depth_covariances",
    "opencv_protocol",
    "perturb_poses",
    "perturb_poses_cov",
    "viewing_scene",
]


@dataclass(frozen=True)
class Scene:
    """Samples and the truth: ``A_i X B_i = Y`` (see ``problem``)."""

    setup: Setup
    T_base_tcp: F64
    T_cam_target: F64
    X: F64
    Y: F64


def perturb_poses(T: F64, noise: PoseNoise, rng: np.random.Generator) -> F64:
    """Poses with the decoupled noise of ``noise`` (parent-frame translation and rotation)."""
    if noise.is_exact:
        return T.copy()
    delta = rng.normal(size=(T.shape[0], 6)) * noise.sigmas6()
    return retract(T, delta)


def perturb_poses_cov(T: F64, covariances: F64, rng: np.random.Generator) -> F64:
    """Poses with decoupled noise of each pose's own covariance ``(n, 6, 6)`` (``(dt, dphi)``)."""
    L = np.linalg.cholesky(covariances)
    return retract(T, np.einsum("nij,nj->ni", L, rng.normal(size=(T.shape[0], 6))))


def depth_covariances(
    T_cam_target: F64,
    rng: np.random.Generator,
    *,
    lateral_mm: float = 0.3,
    depth_ratio: tuple[float, float] = (5.0, 10.0),
    tilt_deg: float = 0.1,
    roll_deg: float = 0.03,
    correlation: float = 0.6,
    ref_distance_m: float = 0.5,
) -> F64:
    """``(n, 6, 6)`` camera covariances of the views ``T_cam_target`` as a depth camera or PnP has them,
    in the frame of each view's line of sight ``u`` (camera to target): across it ``lateral_mm`` x
    ``d / ref_distance_m``, along it a ratio drawn from ``depth_ratio`` times that times
    ``d / ref_distance_m`` again (depth error grows with the square of the distance), rotation about
    the axes across it ``tilt_deg`` x ``d / ref``, about it ``roll_deg`` x ``d / ref``; each
    translation across the line of sight correlated by ``correlation`` with the rotation about the
    other axis across it (a shifted and a tilted board look alike). Rotated into the camera frame."""
    p = np.asarray(T_cam_target, dtype=float)[:, :3, 3]
    n = len(p)
    d = np.linalg.norm(p, axis=1)
    u = p / d[:, None]
    e1 = np.cross(u, np.array([1.0, 0.0, 0.0]))
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    Q = np.stack([e1, np.cross(u, e1), u], axis=2)  # columns: across, across, along the line of sight
    g = d / ref_distance_m
    lat = lateral_mm * 1e-3 * g
    sd = np.column_stack([lat, lat, lat * rng.uniform(*depth_ratio, size=n) * g])
    sr = np.deg2rad(np.column_stack([tilt_deg * g, tilt_deg * g, roll_deg * g]))
    cross = np.zeros((n, 3, 3))
    cross[:, 0, 1] = correlation * sd[:, 0] * sr[:, 1]
    cross[:, 1, 0] = -correlation * sd[:, 1] * sr[:, 0]
    R6 = np.zeros((n, 6, 6))
    R6[:, :3, :3] = R6[:, 3:, 3:] = Q
    C = np.zeros((n, 6, 6))
    C[:, [0, 1, 2], [0, 1, 2]] = sd**2
    C[:, [3, 4, 5], [3, 4, 5]] = sr**2
    C[:, :3, 3:] = cross
    C[:, 3:, :3] = np.transpose(cross, (0, 2, 1))
    out = R6 @ C @ np.transpose(R6, (0, 2, 1))
    return 0.5 * (out + np.transpose(out, (0, 2, 1)))


def add_noise(scene: Scene, noise: NoiseModel, rng: np.random.Generator) -> Scene:
    """The scene with measured (noisy) robot and camera poses; X and Y stay the truth."""
    return replace(
        scene,
        T_base_tcp=perturb_poses(scene.T_base_tcp, noise.robot, rng),
        T_cam_target=perturb_poses(scene.T_cam_target, noise.camera, rng),
    )


def _default_unknowns(setup: Setup) -> tuple[F64, F64]:
    if setup == "eye_in_hand":
        X = T_from_Rt(Rotation.from_euler("xyz", [3.0, -2.0, 91.0], degrees=True).as_matrix(), [0.05, -0.03, 0.08])
        Y = T_from_Rt(Rotation.from_euler("z", 25.0, degrees=True).as_matrix(), [0.65, 0.12, 0.02])
    else:
        X = T_from_Rt(Rotation.from_euler("xyz", [-150.0, 5.0, 80.0], degrees=True).as_matrix(), [0.9, -0.2, 1.1])
        Y = T_from_Rt(Rotation.from_euler("xyz", [0.0, 180.0, 30.0], degrees=True).as_matrix(), [0.0, 0.02, 0.12])
    return X, Y


def viewing_scene(
    rng: np.random.Generator,
    n_poses: int,
    setup: Setup = "eye_in_hand",
    *,
    X: F64 | None = None,
    Y: F64 | None = None,
    distance_m: tuple[float, float] = (0.35, 0.7),
    max_tilt_deg: float = 35.0,
    max_roll_deg: float = 60.0,
    field_of_view: float = 0.25,
) -> Scene:
    """Noise-free samples of a camera looking at a calibration target (either set-up)."""
    X_d, Y_d = _default_unknowns(setup)
    X = X_d if X is None else np.asarray(X, dtype=float)
    Y = Y_d if Y is None else np.asarray(Y, dtype=float)
    d = rng.uniform(*distance_m, size=n_poses)
    uv = rng.uniform(-field_of_view, field_of_view, size=(n_poses, 2))
    p = np.column_stack([uv, np.ones(n_poses)])
    p *= (d / np.linalg.norm(p, axis=1))[:, None]
    tilt_axis = rng.normal(size=(n_poses, 2))
    tilt_axis = np.column_stack([tilt_axis / np.linalg.norm(tilt_axis, axis=1)[:, None], np.zeros(n_poses)])
    tilt = np.deg2rad(rng.uniform(0.0, max_tilt_deg, size=n_poses))
    roll = np.deg2rad(rng.uniform(-max_roll_deg, max_roll_deg, size=n_poses))
    R = (
        Rotation.from_rotvec(tilt_axis * tilt[:, None])
        * Rotation.from_euler("x", 180.0, degrees=True)
        * Rotation.from_euler("z", roll[:, None])
    ).as_matrix()
    B = np.tile(np.eye(4), (n_poses, 1, 1))
    B[:, :3, :3], B[:, :3, 3] = R, p
    if setup == "eye_in_hand":  # A X B = Y with A = M  ->  M = Y B^-1 X^-1
        M = Y @ inv(B) @ inv(X)
    else:  # A = M^-1  ->  M = X B Y^-1
        M = X @ B @ inv(Y)
    return Scene(setup, M, B, X, Y)


def _opencv_pose(rng: np.random.Generator, theta_range: tuple[float, float], t_range: tuple[float, float]) -> F64:
    axis = rng.uniform(-1.0, 1.0, size=3)  # not normalised, as in the original generator
    theta = rng.uniform(*theta_range) * np.sign(rng.uniform(-1.0, 1.0))
    t = rng.uniform(*t_range, size=3) * np.sign(rng.uniform(-1.0, 1.0, size=3))
    return T_from_rotvec(theta * axis, t)


def _noisy_rvec_t(T: F64, rot_sigma: float, trans_sigma: float, rng: np.random.Generator) -> F64:
    rvec = Rotation.from_matrix(T[:3, :3]).as_rotvec() + rng.normal(0.0, rot_sigma, size=3)
    return T_from_rotvec(rvec, T[:3, 3] + rng.normal(0.0, trans_sigma, size=3))


def opencv_protocol(
    rng: np.random.Generator, n_poses: int = 10, *, noise: bool = True, apply_robot_noise: bool = False
) -> Scene:
    """One trial of OpenCV's hand-eye test (eye-in-hand); X = T_tcp_cam, Y = T_base_target."""
    deg = np.pi / 180.0
    X = _opencv_pose(rng, (10 * deg, 50 * deg), (0.05, 0.5))  # cam2gripper
    Y = _opencv_pose(rng, (5 * deg, 85 * deg), (0.5, 3.5))  # target2base
    M = np.zeros((n_poses, 4, 4))
    B = np.zeros((n_poses, 4, 4))
    X_inv = inv(X)
    for i in range(n_poses):
        G = _opencv_pose(rng, (5 * deg, 45 * deg), (0.5, 1.5))  # gripper2base
        Bi = X_inv @ inv(G) @ Y  # target2cam
        if noise:
            Bi = _noisy_rvec_t(Bi, 0.002, 0.005, rng)
            G_noisy = _noisy_rvec_t(G, 0.001, 0.001, rng)
            if apply_robot_noise:
                G = G_noisy
        M[i], B[i] = G, Bi
    return Scene("eye_in_hand", M, B, X, Y)
