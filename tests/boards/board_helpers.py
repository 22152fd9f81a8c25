"""Shared fixtures of the board tests: a distorted camera, rendered views with their truth, and
detections made directly from projected points plus Gaussian noise (for checks of the statistics
that must not depend on a detector)."""

from __future__ import annotations

import numpy as np

from plugins.calibration.boards.detect import Detection, detect_board
from plugins.camera.board_render import render_board, sample_views
from plugins.camera.board_spec import BoardSpec
from plugins.camera.pinhole import CameraModel

TRUE_K = np.array([[620.0, 0.0, 322.4], [0.0, 621.5, 236.9], [0.0, 0.0, 1.0]])
TRUE_D = np.array([-0.30, 0.12, 0.0006, -0.0004, -0.025])  # strong barrel, like a wide-angle lens
CAMERA = CameraModel(640, 480, TRUE_K, TRUE_D, "standard")
TRUE_INTRINSICS = np.r_[TRUE_K[0, 0], TRUE_K[1, 1], TRUE_K[0, 2], TRUE_K[1, 2], TRUE_D]


def rendered_views(
    board: BoardSpec, n: int, seed: int, *, blur: float = 0.8, noise: float = 4.0, camera: CameraModel = CAMERA
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` (T_cam_target, image) pairs with the whole board in view."""
    rng = np.random.default_rng(seed)
    poses = sample_views(board, camera, n, rng)
    return [(T, render_board(board, camera, T, blur_sigma_px=blur, noise_sigma=noise, rng=rng)) for T in poses]


def detected_views(board: BoardSpec, n: int, seed: int, **kw) -> tuple[list[Detection], list[np.ndarray]]:
    """Rendered views, detected; returns the detections and the true poses (every view must be found)."""
    dets, poses = [], []
    for k, (T, img) in enumerate(rendered_views(board, n, seed, **kw)):
        dets.append(detect_board(img, board, f"view_{k:02d}.png"))
        poses.append(T)
    return dets, poses


def noisy_detections(
    board: BoardSpec, camera: CameraModel, n: int, seed: int, sigma_px: float, **view_kw
) -> tuple[list[Detection], list[np.ndarray]]:
    """Exact projections of the board's points plus N(0, sigma_px²) per coordinate; *view_kw* go to
    sample_views (distance_m, max_tilt_deg, ...)."""
    rng = np.random.default_rng(seed)
    poses = sample_views(board, camera, n, rng, **view_kw)
    dets = []
    for k, T in enumerate(poses):
        uv = camera.project(T, board.object_points) + rng.normal(0.0, sigma_px, (board.n_features, 2))
        ids = np.arange(board.n_features)
        dets.append(Detection(f"view_{k:02d}", camera.size, ids, uv, board.object_points.copy(), "simulated"))
    return dets, poses
