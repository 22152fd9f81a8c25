"""The ``depth_gap`` stage fed the messages a simulated camera and a pose source publish (depth images
``32FC1``, the camera's CameraInfo, the target's pose stamped like each image): a hidden per-pixel
pattern is named, the result message carries the report, images without a pose or of another size
are warned about and left out, too few captures give a ``failed`` result instead of an exception."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from gap_stage_helpers import RecordingContext

from engine.messages import CameraInfo, Image, PoseStamped
from plugins.model_gap.depth.report import schema
from plugins.model_gap.stages.depth_gap import DepthGap
from plugins.sim.model_gap.depth_captures import simulate_captures


def run_stage(tmp_path, effect: str | None, n: int, **params) -> RecordingContext:
    caps = simulate_captures(effect, n=n, seed=6)
    ctx = RecordingContext(tmp_path, "depth_gap")
    stage = DepthGap(ctx, DepthGap.Params(**params))
    w, h = caps.size
    stage.on_message("camera_info", CameraInfo(width=w, height=h, K=caps.K, frame_id="camera", stamp_ns=1))
    for k, f in enumerate(caps.frames):
        stamp = 1000 * (k + 1)
        stage.on_message("depth", Image(data=f.depth.astype(np.float32), encoding="32FC1", stamp_ns=stamp))
        stage.on_message("target_pose", PoseStamped(T=f.T_cam_target, frame_id="camera", stamp_ns=stamp))
    stage.on_message("depth", Image(data=np.ones((h, w), np.float32), stamp_ns=99_999))  # no pose: left out
    stage.on_message("depth", Image(data=np.ones((h, w + 1), np.float32), stamp_ns=1000))  # another size
    stage.finish()
    return ctx


def test_the_stage_names_a_hidden_pattern_and_publishes_the_report(tmp_path):
    ctx = run_stage(tmp_path, "polynomial_pattern", 16)  # auto: poses arrived, so known
    ((port, msg),) = ctx.published
    assert port == "result" and msg.kind == "depth_gap" and msg.verdict == "explained", msg.reasons
    doc = json.loads(msg.result_json)
    jsonschema.validate(doc, schema())
    assert doc["named"] == ["polynomial_pattern"] and doc["n_captures"] == 16
    assert msg.metrics["heldout_rms_after_mm"] < 0.9 * msg.metrics["heldout_rms_before_mm"]
    codes = [code for _, code, _ in ctx.events]
    assert "no_target_pose" in codes and "image_size" in codes and "depth_gap" in codes
    assert (tmp_path / "depth_gap" / "depth_gap_report.json").is_file()


def test_too_few_captures_give_a_failed_result_not_an_exception(tmp_path):
    ctx = run_stage(tmp_path, None, 4, target="known")
    ctx.assert_failed("at least 6")


def test_the_parameters_are_checked_when_the_recipe_loads():
    with pytest.raises(ValueError):
        DepthGap.Params(target="guess")
    with pytest.raises(ValueError):
        DepthGap.Params(noise_mm=-0.1)
