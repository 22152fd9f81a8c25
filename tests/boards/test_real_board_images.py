"""Real images: RWHE-Calib's kuka_2 (28 views of a 25x18-square, 15 mm chessboard through a
wide-angle lens, 1920x1200) and its rendered CS_synthetic_1 (15 views, 200 mm squares). Detection runs
once per set (module fixtures); the shared data must be there (a real-data test that skips proves
nothing)."""

from __future__ import annotations

import numpy as np
import pytest
from shared_data import SHARED

from plugins.calibration.boards.board_pose import board_pose
from plugins.calibration.boards.detect import detect_images
from plugins.calibration.boards.intrinsics import calibrate_intrinsics
from plugins.camera.board_spec import parse_board

KUKA = parse_board("chessboard:25x18:15mm")
SYNTH = parse_board("chessboard:10x7:200mm")


@pytest.fixture(scope="module")
def kuka():
    files = sorted((SHARED / "rwhe_kuka2").glob("im_*.png"))
    assert len(files) == 28, f"expected the 28 kuka_2 images in {SHARED / 'rwhe_kuka2'}"
    dets = detect_images(files, KUKA)
    return dets, calibrate_intrinsics(dets)


def test_all_28_kuka_boards_are_found_unambiguously(kuka):
    dets, _ = kuka
    assert len(dets.found) == 28 and not dets.rejected
    assert all(d.n == 408 and not d.ambiguous for d in dets.found)
    assert dets.image_size == (1920, 1200)


def test_kuka_intrinsics_fit_the_wide_angle_lens(kuka):
    _, cal = kuka
    assert cal.usable and cal.rms_px < 0.15, (cal.rms_px, cal.model_choice)  # OpenCV measured 0.08 px
    assert cal.camera.model == "standard"  # the rational model gains 0.2 %: noise
    assert cal.camera.K[0, 0] == pytest.approx(1056.4, abs=2.0)
    assert cal.std()["fx_px"] < 0.2
    assert all(v.rms_px < 0.15 for v in cal.views)


def test_kuka_board_poses_are_consistent_with_the_board_size(kuka):
    """The board stands still and the camera is 0.3-0.6 m away: every pose has the camera in front,
    with mm-level uncertainty."""
    dets, cal = kuka
    for d in dets.found:
        bp = board_pose(d, cal.camera)
        depth = bp.T_cam_target[2, 3]
        assert 0.2 < depth < 1.0
        assert np.all(bp.std()[:3] < 1e-3) and np.all(bp.std()[3:] < np.radians(0.1))


def test_all_15_synthetic_boards_are_found():
    files = sorted((SHARED / "rwhe_synthetic1").glob("im_*.png"))
    assert len(files) == 15
    dets = detect_images(files, SYNTH)
    assert len(dets.found) == 15 and not any(d.ambiguous for d in dets.found)
    cal = calibrate_intrinsics(dets)
    assert cal.usable and cal.rms_px < 0.1, (cal.rms_px, cal.reasons)  # measured 0.023 px
    assert np.all(np.abs(cal.camera.D) < 0.005)  # rendered through a pinhole: no distortion
