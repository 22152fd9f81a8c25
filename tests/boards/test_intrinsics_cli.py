"""vgr calibrate intrinsics: exit codes 0 / 1 / 2, the JSON that later steps load, the report folder."""

from __future__ import annotations

import json

import cv2
import pytest
from board_helpers import rendered_views
from usable_verdicts import USABLE

from engine.cli.main import main
from plugins.calibration.result import CalibrationResult
from plugins.camera.board_spec import parse_board
from plugins.camera.pinhole import CameraModel

SPEC = "charuco:9x6:30mm:22mm:DICT_4X4_50"


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    d = tmp_path_factory.mktemp("views")
    for k, (_, img) in enumerate(rendered_views(parse_board(SPEC), 10, seed=21)):
        cv2.imwrite(str(d / f"im_{k:02d}.png"), img)
    (d / "broken.png").write_bytes(b"\x89PNG broken")
    return d


def test_images_to_a_camera_file(images, tmp_path, capsys):
    out, report = tmp_path / "camera_result.json", tmp_path / "report"
    code = main(["calibrate", "intrinsics", str(images), "--board", SPEC, "--json", str(out), "--report", str(report)])
    text = capsys.readouterr().out
    assert (code, json.loads(out.read_text())["verdict"]) in USABLE, text
    assert "board found in 10 of 11 image(s)" in text and "broken.png: not a readable image" in text
    assert "fx_px" in text and " px" in text and "standard model" in text
    res = CalibrationResult.from_dict(json.loads(out.read_text()))
    assert res.kind == "camera_intrinsics" and res.usable and res.covariance.shape == (9, 9)
    cam = CameraModel.load(out)  # what --intrinsics FILE of later steps reads
    assert cam.size == (640, 480) and cam.model == "standard" and cam.extra["rms_px"] < 0.2
    assert set(cam.extra["per_image_rms_px"]) == {f"im_{k:02d}.png" for k in range(10)}
    assert CameraModel.load(report / "camera.json").K.tolist() == cam.K.tolist()
    for name in ("coverage.png", "result.json", "report.txt", "summary.md", "detections.json"):
        assert (report / name).is_file(), name
    det = json.loads((report / "detections.json").read_text())  # vgr.board_detections/1
    assert det["format"] == "vgr.board_detections/1" and len(det["views"]) == 10
    assert det["rejected"] == [
        {"name": "broken.png", "reason": "not a readable image (corrupt or truncated?)", "unreadable": True}
    ]
    view = det["views"][0]
    assert view["name"] == "im_00.png" and len(view["ids"]) == len(view["image_points_px"]) > 10
    assert cam.to_camera_info().distortion_model == "plumb_bob"


def test_bad_input_exits_2(images, tmp_path, capsys):
    assert main(["calibrate", "intrinsics", str(images), "--board", "chessboard:9x6"]) == 2
    assert "bad input: board 'chessboard:9x6'" in capsys.readouterr().err
    assert main(["calibrate", "intrinsics", str(images / "broken.png"), "--board", SPEC]) == 2
    assert "none of the 1 image(s) could be read" in capsys.readouterr().err
    assert main(["calibrate", "intrinsics", str(tmp_path), "--board", SPEC]) == 2
    assert "no image files" in capsys.readouterr().err


def test_a_board_not_in_the_images_exits_1(images, capsys):
    one = str(images / "im_00.png")  # one image: a chessboard search that fails takes ~1.5 s per image
    code = main(["calibrate", "intrinsics", one, "--board", "chessboard:10x7:30mm"])
    text = capsys.readouterr().out
    assert code == 1 and "verdict FAILED" in text and "found in 0 of 1 image(s)" in text
    assert "no chessboard of 9x6 inner corners found" in text
