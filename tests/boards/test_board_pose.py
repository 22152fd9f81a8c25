"""Board pose per image: its covariance is honest (chi-square over many views), in the hand-eye
solver's perturbation; ambiguous boards are refused."""

from __future__ import annotations

import numpy as np
import pytest
from board_helpers import CAMERA, detected_views, noisy_detections
from scipy import stats

from engine.transforms import pose_delta, retract
from plugins.calibration.boards.board_pose import AmbiguousBoardError, board_pose, pose_jacobian
from plugins.calibration.boards.detect import detect_board
from plugins.calibration.handeye.noise import PoseNoise
from plugins.camera.board_render import look_at, render_board
from plugins.camera.board_spec import parse_board
from plugins.camera.pinhole import CameraModel

CHESS = parse_board("chessboard:10x7:30mm")
FISHEYE = CameraModel(640, 480, CAMERA.K, [0.05, -0.01, 0.002, -0.001], "fisheye")


@pytest.mark.parametrize("camera", [CAMERA, FISHEYE], ids=["standard", "fisheye"])
def test_the_jacobian_is_the_derivative_of_the_handeye_perturbation(camera):
    T = look_at([0.2, 0.05, 0.45], [0.15, 0.1, 0.0], (0.3, 1, 0))
    J = pose_jacobian(camera, T, CHESS.object_points)
    h = 1e-7
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        num = (camera.project(retract(T, d)[0], CHESS.object_points) - camera.project(retract(T, -d)[0],
               CHESS.object_points)).ravel() / (2 * h)  # fmt: skip
        np.testing.assert_allclose(J[:, k], num, rtol=1e-4, atol=1e-3)
    # the same order as the hand-eye solver's per-sample camera noise: (tx, ty, tz, rx, ry, rz)
    assert PoseNoise((1, 2, 3), (4, 5, 6)).sigmas6().tolist() == [4, 5, 6, 1, 2, 3]


@pytest.mark.parametrize("camera", [CAMERA, FISHEYE], ids=["standard", "fisheye"])
@pytest.mark.parametrize("given_sigma", [False, True], ids=["sigma-estimated", "sigma-given"])
def test_board_poses_lie_within_their_covariance(camera, given_sigma):
    """Exact corners + Gaussian noise (0.2 px), 300 views: the Mahalanobis² of each pose's error is
    chi-square(6): mean 6 (its standard error 0.2), 5 % beyond the 95 % quantile."""
    dets, poses = noisy_detections(CHESS, camera, 300, seed=8, sigma_px=0.2)
    m2 = []
    for det, T in zip(dets, poses, strict=True):
        bp = board_pose(det, camera, sigma_px=0.2 if given_sigma else None)
        e = pose_delta(bp.T_cam_target, T)[0]
        m2.append(e @ np.linalg.solve(bp.covariance, e))
    m2 = np.array(m2)
    assert abs(m2.mean() - 6.0) < 0.9, m2.mean()
    beyond = int(np.sum(m2 > stats.chi2.ppf(0.95, 6)))
    assert 4 <= beyond <= 28, beyond  # binomial(300, 0.05): 15, 99.9 % within [4, 28]


def test_rendered_charuco_poses_are_near_their_covariance():
    """Through rendering and OpenCV's detector the corner errors are not quite independent; the
    measured inflation (mean Mahalanobis² about 12 instead of 6 for these views) is bounded here."""
    board = parse_board("charuco:9x6:30mm:22mm:DICT_4X4_50")
    dets, poses = detected_views(board, 12, seed=11)
    m2 = []
    for det, T in zip(dets, poses, strict=True):
        bp = board_pose(det, CAMERA)
        e = pose_delta(bp.T_cam_target, T)[0]
        m2.append(e @ np.linalg.solve(bp.covariance, e))
        assert np.linalg.norm(e[:3]) < 1e-3 and np.linalg.norm(e[3:]) < np.radians(0.5)
    assert np.mean(m2) < 4 * 6.0, np.round(m2, 1)


def test_an_ambiguous_board_is_refused_and_says_why():
    board = parse_board("chessboard:9x7:30mm")
    T = look_at([0.12, 0.1, 0.45], [0.135, 0.105, 0.0], (0, 1, 0))
    det = detect_board(render_board(board, CAMERA, T), board, "sym.png")
    with pytest.raises(AmbiguousBoardError, match=r"sym\.png: the board looks the same turned by 180 degrees"):
        board_pose(det, CAMERA)
    bp = board_pose(det, CAMERA, allow_ambiguous=True)
    e = pose_delta(bp.T_cam_target, T)[0]
    turned = np.linalg.norm(e[3:]) > np.radians(179)  # either the truth or the truth turned 180 degrees
    assert turned or np.linalg.norm(e[3:]) < np.radians(0.2)


def test_pose_of_an_image_of_another_size_is_refused():
    det, _ = noisy_detections(CHESS, CAMERA, 1, seed=1, sigma_px=0.1)
    other = CameraModel(800, 600, CAMERA.K, CAMERA.D)
    with pytest.raises(ValueError, match="image 640x480 but the camera is calibrated for 800x600"):
        board_pose(det[0], other)
