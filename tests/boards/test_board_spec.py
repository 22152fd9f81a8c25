"""Board specs and board files: what COLSxROWS counts, the board frame, ambiguity, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from plugins.camera.board_spec import BoardSpec, BoardSpecError, load_board, parse_board


def test_chessboard_counts_squares_and_its_features_are_the_inner_corners():
    b = parse_board("chessboard:25x18:15mm")
    assert (b.kind, b.cols, b.rows, b.square_m) == ("chessboard", 25, 18, 0.015)
    assert b.grid_shape == (24, 17) and b.n_features == 408
    assert "25x18 squares" in b.describe() and "24x17 inner corners" in b.describe()
    p = b.object_points
    assert p.shape == (408, 3) and np.all(p[:, 2] == 0)
    # origin at the grid's bottom-left corner: the first inner corner is one square from it
    np.testing.assert_allclose(p[0], [0.015, 0.015, 0.0])
    np.testing.assert_allclose(p[1], [0.030, 0.015, 0.0])  # ids run along x first
    np.testing.assert_allclose(p[24], [0.015, 0.030, 0.0])
    assert not b.ambiguous  # 25 + 18 odd: the black origin square names one corner


@pytest.mark.parametrize(
    ("spec", "ambiguous"),
    [
        ("chessboard:9x7:20mm", True),
        ("chessboard:8x8:20mm", True),
        ("chessboard:10x7:20mm", False),
        ("circles:5x4:20mm", True),
        ("circles:4x11:20mm:asymmetric", False),
        ("circles:4x10:20mm:asymmetric", True),
        ("charuco:8x8:30mm:20mm:DICT_4X4_50", False),
    ],
)
def test_ambiguity_follows_the_half_turn_symmetry(spec, ambiguous):
    b = parse_board(spec)
    assert b.ambiguous is ambiguous
    if b.kind == "charuco":
        return
    # geometric check: a half turn about the pattern's centre maps the feature set onto itself
    p = b.object_points[:, :2]
    q = p.mean(axis=0) * 2 - p
    same_set = all(np.min(np.linalg.norm(p - x, axis=1)) < 1e-9 for x in q)
    if b.kind == "chessboard":  # the squares' colours must follow too: COLS + ROWS even
        assert ambiguous == (same_set and (b.cols + b.rows) % 2 == 0)
    else:
        assert ambiguous == same_set


def test_charuco_points_are_opencv_corners_in_the_z_out_frame():
    b = parse_board("charuco:12x9:60mm:45mm:DICT_5X5_100")
    assert b.dictionary == "DICT_5X5_100" and b.n_features == 11 * 8
    cv = np.asarray(b.cv_board().getChessboardCorners()).reshape(-1, 3)
    np.testing.assert_allclose(b.object_points[:, 0], cv[:, 0], atol=1e-6)  # OpenCV's are float32
    np.testing.assert_allclose(b.object_points[:, 1], 9 * 0.06 - cv[:, 1], atol=1e-6)  # y up instead of down
    assert parse_board("charuco:12x9:60mm:45mm:dict_5x5_100:legacy").legacy


def test_asymmetric_circles_follow_opencv_spacing():
    b = parse_board("circles:4x11:20mm:asymmetric")
    p = b.object_points
    assert p.shape == (44, 3)
    top_row = p[p[:, 1] == p[:, 1].max()]  # OpenCV's first row: not shifted
    np.testing.assert_allclose(np.sort(top_row[:, 0]), [0.0, 0.04, 0.08, 0.12])
    assert sorted(set(np.round(p[:, 1], 9))) == pytest.approx([k * 0.02 for k in range(11)])


@pytest.mark.parametrize(
    "spec", ["chessboard:25x18:15mm", "charuco:12x9:60mm:45mm:DICT_5X5_100:legacy", "circles:4x11:2cm:asymmetric"]
)
def test_spec_and_board_file_round_trip(spec, tmp_path):
    b = parse_board(spec)
    assert parse_board(b.spec) == b
    y = tmp_path / "board.yaml"
    y.write_text(yaml.safe_dump(b.to_dict()))
    assert load_board(y) == b and parse_board(str(y)) == b
    j = tmp_path / "board.json"
    j.write_text(json.dumps({"spec": spec}))
    assert parse_board(j) == b


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("chessboard:25x18", "expected 3 fields"),
        ("chessboard:25x18:15", "has no unit"),
        ("chessboard:25x18:15 inch", "is not a length"),
        ("chessboard:25by18:15mm", "is not COLSxROWS"),
        ("chessboard:3x3:15mm", "needs 4..200 squares"),
        ("chessboard:25x18:1000m", "outside 0.1 mm .. 5 m"),
        ("charuco:12x9:60mm:70mm:DICT_5X5_100", "must be smaller than the square"),
        ("charuco:30x30:10mm:7mm:DICT_4X4_50", "only 50"),
        ("charuco:12x9:60mm:45mm:DICT_FOO", "unknown ArUco dictionary"),
        ("charuco:12x9:60mm:45mm", "expected 5 fields"),
        ("circles:4x11:20mm:hexagonal", "optionally 'asymmetric'"),
        ("hexagons:4x4:1mm", "unknown type 'hexagons'"),
        ("", "unknown type"),
    ],
)
def test_bad_specs_say_what_to_write(spec, message):
    with pytest.raises(BoardSpecError, match=message) as exc:
        parse_board(spec)
    if "unknown type" not in message:
        assert "write" in str(exc.value) or "use" in str(exc.value)


def test_a_missing_board_file_is_a_board_spec_error(tmp_path):
    with pytest.raises(BoardSpecError, match="no such file"):
        parse_board(str(tmp_path / "missing.yaml"))


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("type: chessboard\ncols: 9\nrows: 6\nsquare: 20\n", "unknown field"),
        ("type: chessboard\ncols: 9.5\nrows: 6\nsquare_mm: 20\n", "whole number"),
        ("[1, 2", "cannot read"),
        ("type: chessboard\ncols: 9\nrows: 6\n", "square_mm"),
    ],
)
def test_bad_board_files(tmp_path, text, says):
    f = tmp_path / "b.yaml"
    f.write_text(text)
    with pytest.raises(BoardSpecError, match=says):
        load_board(f)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=60))
def test_garbage_is_a_board_spec_error_or_a_board(text):
    try:
        b = parse_board(text)
    except BoardSpecError as exc:
        assert str(exc)
    else:
        assert isinstance(b, BoardSpec)


_piece = st.one_of(
    st.sampled_from(["chessboard", "charuco", "circles", "CHESSBOARD", "x"]),
    st.from_regex(r"-?\d{0,4}[xX]\d{0,4}", fullmatch=True),
    st.from_regex(r"-?\d{0,3}(\.\d{0,3})?(mm|cm|m|km|)", fullmatch=True),
    st.sampled_from(["DICT_4X4_50", "DICT_6X6_1000", "dict_apriltag_36h11", "legacy", "asymmetric", ""]),
)


@settings(max_examples=400, deadline=None)
@given(st.lists(_piece, min_size=1, max_size=6))
def test_nearly_right_specs_are_a_board_spec_error_or_a_valid_board(parts):
    try:
        b = parse_board(":".join(parts))
    except BoardSpecError as exc:
        assert str(exc)
    else:
        assert b.n_features >= 4 and np.all(np.isfinite(b.object_points))
        assert parse_board(b.spec) == b
