"""The ``camera_gap`` stage on rendered board images (plugins/camera/board_render.py: supersampled
rays through the lens, blur, grey-level noise; the real detector finds the corners): a hidden third
radial term is named, the result message carries the report, bad images are warned about, too few
views give a ``failed`` result instead of an exception."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gap_stage_helpers import RecordingContext

from engine.messages import Image
from plugins.camera.board_render import render_board, sample_views
from plugins.camera.board_spec import parse_board
from plugins.camera.pinhole import CameraModel
from plugins.model_gap.camera.report import schema
from plugins.model_gap.stages.camera_gap import CameraGap

BOARD = "chessboard:9x7:20mm"


def rendered(n: int, seed: int) -> list[Image]:
    """*n* images of the board through a lens with a strong third radial term (k3 = -0.3)."""
    board = parse_board(BOARD)
    cam = CameraModel(
        640, 480, np.array([[450.0, 0, 322], [0, 450, 238], [0, 0, 1]]), np.array([-0.2, 0.05, 0, 0, -0.3])
    )
    rng = np.random.default_rng(seed)
    poses = sample_views(board, cam, n, rng, max_tilt_deg=40.0)
    return [
        Image(
            data=render_board(board, cam, T, supersample=2, blur_sigma_px=0.6, noise_sigma=2.0, rng=rng),
            encoding="mono8",
            stamp_ns=k,
        )
        for k, T in enumerate(poses)
    ]


def run_stage(tmp_path, images: list[Image]) -> RecordingContext:
    ctx = RecordingContext(tmp_path, "camera_gap")
    stage = CameraGap(ctx, CameraGap.Params(board=BOARD))
    for im in images:
        stage.on_message("image", im)
    stage.finish()
    return ctx


@pytest.mark.slow
def test_the_stage_names_the_hidden_k3_in_rendered_images(tmp_path):
    blank = Image(data=np.full((480, 640), 128, np.uint8), encoding="mono8", stamp_ns=99)
    ctx = run_stage(tmp_path, [*rendered(20, seed=2), blank])
    ((port, msg),) = ctx.published
    assert port == "result" and msg.kind == "camera_gap"
    doc = json.loads(msg.result_json)
    import jsonschema

    jsonschema.validate(doc, schema())
    assert doc["named"][:1] == ["radial_k3"], doc["reason"]
    assert msg.metrics["heldout_rms_after_px"] < 0.7 * msg.metrics["heldout_rms_before_px"]
    assert any(code == "board_not_found" for _, code, _ in ctx.events)
    assert (tmp_path / "camera_gap" / "camera_gap_report.json").is_file()


def test_too_few_views_give_a_failed_result_not_an_exception(tmp_path):
    ctx = run_stage(tmp_path, rendered(3, seed=1))
    ctx.assert_failed("at least 6")


def test_a_wrong_board_spec_is_refused_by_the_parameters():
    with pytest.raises(ValueError):
        CameraGap.Params(board="chessboard:1x7:20mm")
