"""Detection on rendered boards with known truth; every kind of bad image gives a reason, never a crash."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from board_helpers import CAMERA, rendered_views

from plugins.calibration.boards.detect import (
    BoardNotFoundError,
    detect_board,
    detect_images,
)
from plugins.camera.board_render import look_at, render_board
from plugins.camera.board_spec import parse_board

UNAMBIGUOUS = [
    ("chessboard:10x7:30mm", 0.10),
    ("charuco:9x6:30mm:22mm:DICT_4X4_50", 0.30),  # OpenCV refines ChArUco corners less finely
    ("charuco:8x6:30mm:22mm:DICT_5X5_100:legacy", 0.30),
    ("circles:4x11:15mm:asymmetric", 0.15),
]


@pytest.mark.parametrize(("spec", "max_rms"), UNAMBIGUOUS)
def test_each_board_kind_is_found_where_it_was_drawn(spec, max_rms):
    board = parse_board(spec)
    for k, (T, img) in enumerate(rendered_views(board, 4, seed=3)):
        det = detect_board(img, board, f"v{k}")
        truth = CAMERA.project(T, board.object_points)[det.ids]
        err = np.linalg.norm(det.image_points - truth, axis=1)
        assert not det.ambiguous
        assert np.sqrt(np.mean(err**2)) < max_rms, (k, err.max())
        np.testing.assert_array_equal(det.object_points, board.object_points[det.ids])
        if board.kind != "charuco":
            assert det.n == board.n_features


def test_a_board_turned_upside_down_keeps_its_numbering():
    board = parse_board("chessboard:10x7:30mm")
    centre = np.r_[0.15, 0.105, 0.0]
    for up in ((0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)):  # rolled by 0, 180, +-90 deg
        T = look_at(centre + np.array([0.03, -0.05, 0.42]), centre, up)
        det = detect_board(render_board(board, CAMERA, T), board)
        truth = CAMERA.project(T, board.object_points)
        assert np.abs(det.image_points - truth).max() < 0.3, up


@pytest.mark.parametrize("spec", ["chessboard:9x7:30mm", "circles:6x5:40mm"])
def test_symmetric_boards_are_found_but_marked_ambiguous(spec):
    board = parse_board(spec)
    ((_, img),) = rendered_views(board, 1, seed=4)
    det = detect_board(img, board)
    assert det.ambiguous and det.n == board.n_features


def test_a_partial_charuco_view_is_kept():
    board = parse_board("charuco:9x6:30mm:22mm:DICT_4X4_50")
    centre = np.r_[0.0, 0.09, 0.0]  # looking at the board's left edge: its right part is out of view
    T = look_at(centre + np.array([0.0, 0.0, 0.25]), centre, (0, 1, 0))
    det = detect_board(render_board(board, CAMERA, T), board)
    assert 6 <= det.n < board.n_features
    truth = CAMERA.project(T, board.object_points)[det.ids]
    assert np.abs(det.image_points - truth).max() < 0.5


def test_colour_alpha_16_bit_and_float_images_are_read():
    board = parse_board("chessboard:10x7:30mm")
    ((T, img),) = rendered_views(board, 1, seed=5)
    variants = {
        "bgr": cv2.cvtColor(img, cv2.COLOR_GRAY2BGR),
        "bgra": cv2.cvtColor(img, cv2.COLOR_GRAY2BGRA),
        "16 bit": img.astype(np.uint16) * 257,
        "float": img.astype(np.float32) / 255.0,
    }
    for name, im in variants.items():
        det = detect_board(im, board)
        assert np.abs(det.image_points - CAMERA.project(T, board.object_points)).max() < 0.5, name


def test_every_bad_image_is_listed_with_its_reason(tmp_path):
    board = parse_board("chessboard:10x7:30mm")
    ((_, img),) = rendered_views(board, 1, seed=6)
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), img)
    jpg = tmp_path / "good.jpg"
    cv2.imwrite(str(jpg), img, [cv2.IMWRITE_JPEG_QUALITY, 98])
    bmp = tmp_path / "good.bmp"
    cv2.imwrite(str(bmp), img)
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(good.read_bytes()[:200])
    garbage = tmp_path / "garbage.jpg"
    garbage.write_bytes(b"not an image at all")
    empty = tmp_path / "empty.bmp"
    empty.write_bytes(b"")
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.resize(img, (320, 240)))
    files = [good, jpg, bmp, corrupt, garbage, empty, text, blank, small, tmp_path / "missing.png"]
    out = detect_images(files, board, workers=2)
    assert [d.name for d in out.found] == [str(good), str(jpg), str(bmp)]
    reasons = {r.name.rsplit("/", 1)[-1]: (r.reason, r.unreadable) for r in out.rejected}
    assert reasons["corrupt.png"] == ("not a readable image (corrupt or truncated?)", True)
    assert reasons["garbage.jpg"][1] and reasons["empty.bmp"] == ("empty file", True)
    assert "not an image file type" in reasons["notes.txt"][0]
    assert reasons["missing.png"] == ("no such file", True)
    assert "no chessboard of 9x6 inner corners found" in reasons["blank.png"][0] and not reasons["blank.png"][1]
    assert "image size 320x240 differs from 640x480" in reasons["small.png"][0]
    assert "board found in 3 of 10 image(s)" in out.summary()
    # a folder stands for its images
    assert len(detect_images([tmp_path], board).found) == 3


def test_wrong_board_size_and_dictionary_are_reported():
    board = parse_board("chessboard:10x7:30mm")
    ((_, img),) = rendered_views(board, 1, seed=7)
    with pytest.raises(BoardNotFoundError, match="is COLSxROWS the number of squares"):
        detect_board(img, parse_board("chessboard:9x6:30mm"))
    charuco = parse_board("charuco:9x6:30mm:22mm:DICT_4X4_50")
    ((_, img),) = rendered_views(charuco, 1, seed=7)
    with pytest.raises(BoardNotFoundError, match="no DICT_6X6_50 marker found"):
        detect_board(img, parse_board("charuco:9x6:30mm:22mm:DICT_6X6_50"))
