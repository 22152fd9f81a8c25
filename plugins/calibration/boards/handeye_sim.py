"""Simulated hand-eye data with known truth: robot poses, board corners, optional robot-pose noise.

For the tests and benchmarks of :mod:`.handeye_images` (the statistics of its estimate and its
covariance, the Cramér–Rao bound). Eye in hand: the camera views ``T_cam_target`` come from
:func:`.render.sample_views` (the whole board in the image), and with the true hand-eye ``X =
T_tcp_cam`` and board pose ``Y = T_base_target`` the robot's flange poses are ``M_i = Y B_i⁻¹ X⁻¹``
(so that ``B_i = X⁻¹ M_i⁻¹ Y``, :func:`plugins.calibration.handeye.problem.model_camera_poses`). The
robot poses handed to the solver are ``M_i`` perturbed by ``N(0, robot.sd6())``
(:func:`engine.transforms.retract`); the corners are either the exact projections plus
``N(0, sigma_px²)`` per coordinate (``render=False``: known corner noise, the model of the pixel
refinement) or detected in rendered images (:func:`.render.render_board`, :func:`.detect.detect_board`:
the detector's own error, shared in part by a view's corners).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from engine.transforms import T_from_rotvec, inv, retract
from plugins.calibration.boards.detect import BoardNotFoundError, Detection, detect_board
from plugins.calibration.boards.reprojection import RobotNoise
from plugins.camera.board_render import render_board, sample_views
from plugins.camera.board_spec import BoardSpec
from plugins.camera.pinhole import CameraModel

F64 = NDArray[np.float64]

__all__ = ["SIM_CAMERA", "TRUE_X", "TRUE_Y", "SimulatedHandEye", "simulate_handeye"]


# a 640x480 camera with barrel distortion (a small industrial camera with a wide lens)
SIM_CAMERA = CameraModel(
    640, 480, np.array([[600.0, 0.0, 318.5], [0.0, 600.5, 241.2], [0.0, 0.0, 1.0]]),
    np.array([-0.2, 0.08, 0.0003, -0.0002, -0.01]), "standard",
)  # fmt: skip
# a camera 10 cm off the flange axis, tilted; a board on the table in front of the robot, face up
TRUE_X = T_from_rotvec(np.radians((3.0, -5.0, 90.0)), (0.03, -0.10, 0.08))
TRUE_Y = T_from_rotvec(np.radians((0.0, 0.0, 30.0)), (0.70, -0.10, 0.02))


@dataclass(frozen=True, eq=False)
class SimulatedHandEye:
    """Views (detections), the robot poses as measured and as true, and the true ``X``, ``Y``."""

    views: list[Detection]
    T_base_tcp: F64  # as measured (with the robot noise)
    T_base_tcp_true: F64
    X: F64
    Y: F64


def simulate_handeye(
    board: BoardSpec,
    camera: CameraModel,
    n_views: int,
    rng: np.random.Generator,
    *,
    sigma_px: float = 0.1,
    robot_noise: RobotNoise | None = None,
    render: bool = False,
    blur_px: float = 0.8,
    grey_noise: float = 2.0,
    X: F64 = TRUE_X,
    Y: F64 = TRUE_Y,
) -> SimulatedHandEye:
    """``n_views`` eye-in-hand views of ``board`` (module docstring); with ``render`` the views where
    the detector does not find the board are left out (with their robot poses)."""
    B = np.stack(sample_views(board, camera, n_views, rng))
    M_true = Y @ inv(B) @ inv(X)
    views: list[Detection] = []
    keep: list[int] = []
    for k, T in enumerate(B):
        name = f"view_{k:02d}.png"
        if render:
            img = render_board(board, camera, T, blur_sigma_px=blur_px, noise_sigma=grey_noise, rng=rng)
            try:
                det = detect_board(img, board, name)
            except BoardNotFoundError:
                continue
        else:
            uv = camera.project(T, board.object_points) + rng.normal(0.0, sigma_px, (board.n_features, 2))
            ids = np.arange(board.n_features)
            det = Detection(name, camera.size, ids, uv, board.object_points.copy(), "simulated")
        views.append(det)
        keep.append(k)
    M_true = M_true[keep]
    M = M_true.copy()
    if robot_noise is not None:
        M = retract(M_true, rng.normal(0.0, 1.0, (len(keep), 6)) * robot_noise.sd6())
    return SimulatedHandEye(views, M, M_true, X.copy(), Y.copy())
