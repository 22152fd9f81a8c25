"""Helpers of the depth-gap tests: range errors outside the catalog written into simulated depth
images, flying pixels at known places, a vgr recording of simulated captures (the topics and types a
``sim_camera`` stage records), and ``vgr gap --json`` run in-process."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, Writer

from engine.cli.main import main
from engine.messages import CameraInfo, FrameTransforms, Image, Transform, codec
from engine.messages.schemas import descriptor_set
from plugins.model_gap.depth.data import DepthCaptures, DepthFrame

RangeError = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]  # (r, x, y) -> added range (m)


def _rays(caps: DepthCaptures) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w, h = caps.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    x, y = (u - caps.K[0, 2]) / caps.K[0, 0], (v - caps.K[1, 2]) / caps.K[1, 1]
    return x, y, np.sqrt(1.0 + x * x + y * y)


def add_range_error(caps: DepthCaptures, error: RangeError) -> DepthCaptures:
    """*caps* with ``error(r, x, y)`` added to every pixel's range along its ray (in place, returned)."""
    x, y, norm = _rays(caps)
    caps.frames = [
        DepthFrame(f.name, (f.depth * norm + error(f.depth * norm, x, y)) / norm, f.T_cam_target, f.target_extent_m)
        for f in caps.frames
    ]
    return caps


def add_flying_pixels(caps: DepthCaptures, per_capture: int, seed: int = 0) -> list[int]:
    """Move *per_capture* valid pixels of each capture 3-15 cm along their ray (in place); the counts."""
    rng = np.random.default_rng(seed)
    _, _, norm = _rays(caps)
    counts = []
    for f in caps.frames:
        flat = f.depth.reshape(-1)
        pick = rng.choice(np.flatnonzero(np.isfinite(flat)), per_capture, replace=False)
        shift = rng.uniform(0.03, 0.15, per_capture) * rng.choice((-1.0, 1.0), per_capture)
        flat[pick] += shift / norm.reshape(-1)[pick]
        counts.append(per_capture)
    return counts


def write_recording(
    path: Path, caps: DepthCaptures, stage: str = "camera", target: str = "plate", port: str = "depth"
) -> Path:
    """*caps* as a vgr recording of a ``sim_camera`` stage: ``/<stage>/<port>`` (Image 32FC1),
    ``/<stage>/camera_info`` and ``/<stage>/truth/part_poses`` (the camera's and the target's true
    poses in ``world``, the camera frame ``camera``), one of each per capture."""
    w, h = caps.size
    with path.open("wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="vgr", library="vgr tests")
        writer.add_metadata("vgr.run", {"run_id": "test", "process": "main", "clock_start_ns": "0"})
        channels: dict[str, int] = {}

        def put(port: str, msg: object, stamp: int) -> None:
            topic = f"/{stage}/{port}"
            if topic not in channels:
                sid = writer.register_schema(name=msg.SCHEMA, encoding="protobuf", data=descriptor_set(msg.SCHEMA))
                meta = {"stage": stage, "port": port, "type": msg.TYPE, "process": "main", "role": "sensor"}
                channels[topic] = writer.register_channel(topic, "protobuf", sid, meta)
            data = codec.encode_payload(msg)
            writer.add_message(channels[topic], log_time=stamp, data=data, publish_time=stamp, sequence=stamp)

        T_world_target = np.eye(4)
        for k, frame in enumerate(caps.frames):
            stamp = (k + 1) * 100_000_000
            depth = np.asarray(frame.depth, np.float32)
            put(port, Image(data=depth, encoding="32FC1", frame_id="camera", stamp_ns=stamp), stamp)
            put("camera_info", CameraInfo(width=w, height=h, K=caps.K, frame_id="camera", stamp_ns=stamp), stamp)
            T_world_cam = T_world_target @ np.linalg.inv(np.asarray(frame.T_cam_target, float))
            truth = [
                Transform(frame_id="world", child_frame_id=f"truth/{name}", T=T, stamp_ns=stamp)
                for name, T in ((target, T_world_target), ("camera", T_world_cam))
            ]
            put("truth/part_poses", FrameTransforms(stamp_ns=stamp, transforms=truth), stamp)
        writer.finish()
    return path


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} in a strict JSON document")


def run_json(capsys, *argv: str) -> tuple[int, dict]:
    """``vgr gap ARGV --json`` in-process: the exit code and the document (strict JSON on stdout:
    NaN or Infinity fail)."""
    code = main(["gap", *argv, "--json"])
    out = capsys.readouterr().out
    return code, json.loads(out, parse_constant=_no_constant)


def invalid(capsys, *argv: str) -> dict:
    """``vgr gap ARGV --json`` must refuse: exit code 2 and a ``vgr.invalid/1`` document."""
    code, doc = run_json(capsys, *argv)
    assert code == 2 and doc["format"] == "vgr.invalid/1" and doc["exit_code"] == 2, doc
    return doc
