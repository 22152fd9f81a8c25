"""A fake ``pyrealsense2`` module: a pipeline that delivers scripted z16 (and RGB) frames.

Only the calls vgr makes exist, with pyrealsense2's names (checked against pyrealsense2 2.59).
Live: ``config.enable_stream/enable_device``, ``pipeline.start/wait_for_frames/poll_for_frames/stop``,
the profile's device (depth scale) and stream intrinsics; frames come one per wait (warm-up and the
dropped waiting frame set consume frames too, as on a camera). Recording: ``context().load_device``
-> playback device (``set_real_time``, ``current_status``), ``query_sensors`` -> sensors with stream
profiles, ``open``/``start(syncer)``/``stop``/``close``; ``syncer.try_wait_for_frames`` gives the frames
in order, then ``(False, None)`` with the playback ``stopped``. ``align`` is the identity here (the
scripted depth is already in the colour camera).
"""

from __future__ import annotations

import enum
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# pyrealsense2's enums, with its names and values
stream = enum.Enum("stream", {"depth": 1, "color": 2})
format = enum.Enum("format", {"z16": 1, "rgb8": 5})
distortion = enum.Enum(
    "distortion", "none modified_brown_conrady inverse_brown_conrady ftheta brown_conrady kannala_brandt4", start=0
)
playback_status = enum.Enum("playback_status", "unknown playing paused stopped", start=0)


@dataclass
class Intrinsics:
    width: int
    height: int
    fx: float
    fy: float
    ppx: float
    ppy: float
    model: distortion = distortion.brown_conrady
    coeffs: list[float] = field(default_factory=lambda: [0.0] * 5)


@dataclass
class FakeCamera:
    """What the fake device holds: scripted frames, intrinsics, depth scale; and what was asked of it."""

    frames: list[np.ndarray]  # z16 (H, W) uint16
    intrinsics: Intrinsics
    depth_scale: float = 0.001
    colors: list[np.ndarray] | None = None  # (H, W, 3) uint8, aligned to depth
    color_intrinsics: Intrinsics | None = None
    start_error: Exception | None = None
    recording_has_color: bool = True
    # filled by the fake
    streams: list[tuple[Any, ...]] = field(default_factory=list)
    device_serial: str | None = None
    recording: str | None = None
    real_time: bool = True
    real_time_when_started: list[bool] = field(default_factory=list)
    opened: list[list[Any]] = field(default_factory=list)
    sensors_stopped: int = 0
    loads: int = 0
    waits: int = 0
    polls: int = 0
    stopped: int = 0
    aligned: int = 0  # framesets passed through rs.align (the fake's frames are aligned already)
    cursor: int = 0


class _Frame:
    def __init__(self, data: np.ndarray, number: int) -> None:
        self._data, self._number = data, number

    def __bool__(self) -> bool:
        return True

    def get_data(self) -> np.ndarray:
        return self._data

    def get_frame_number(self) -> int:
        return self._number

    def get_timestamp(self) -> float:
        return 33.333 * self._number


class _Frameset:
    def __init__(self, cam: FakeCamera, k: int) -> None:
        self.cam, self.k = cam, k

    def get_frame_number(self) -> int:
        return self.k

    def get_depth_frame(self) -> _Frame:
        return _Frame(self.cam.frames[self.k], self.k)

    def get_color_frame(self) -> _Frame | None:
        if self.cam.colors is None:
            return None
        return _Frame(self.cam.colors[self.k], self.k)


def make_module(cam: FakeCamera) -> types.ModuleType:
    rs = types.ModuleType("pyrealsense2")

    class config:  # noqa: N801
        def enable_stream(self, s: stream, w: int, h: int, f: format, fps: int) -> None:
            cam.streams.append((s, w, h, f, fps))

        def enable_device(self, serial: str) -> None:
            cam.device_serial = serial

    class _Playback:
        def set_real_time(self, on: bool) -> None:
            cam.real_time = on

        def current_status(self) -> playback_status:
            return playback_status.stopped if cam.cursor >= len(cam.frames) else playback_status.playing

    class _DepthSensor:
        def get_depth_scale(self) -> float:
            return cam.depth_scale

    class _VideoProfile:
        def __init__(self, s: stream, intr: Intrinsics) -> None:
            self.s, self.intr = s, intr

        def stream_type(self) -> stream:
            return self.s

        def as_video_stream_profile(self) -> _VideoProfile:
            return self

        def get_intrinsics(self) -> Intrinsics:
            return self.intr

    def _color_profile() -> _VideoProfile:
        return _VideoProfile(stream.color, cam.color_intrinsics or cam.intrinsics)

    class _RecordedSensor:
        def __init__(self, profiles: list[_VideoProfile]) -> None:
            self.profiles = profiles

        def get_stream_profiles(self) -> list[_VideoProfile]:
            return self.profiles

        def open(self, profiles: list[_VideoProfile]) -> None:
            cam.opened.append([p.s for p in profiles])

        def start(self, sink: Any) -> None:
            cam.real_time_when_started.append(cam.real_time)

        def stop(self) -> None:
            cam.sensors_stopped += 1

        def close(self) -> None:
            pass

    class _Device:
        def first_depth_sensor(self) -> _DepthSensor:
            return _DepthSensor()

        def as_playback(self) -> _Playback:
            assert cam.recording is not None, "as_playback on a live device"
            return _Playback()

        def query_sensors(self) -> list[_RecordedSensor]:
            sensors = [_RecordedSensor([_VideoProfile(stream.depth, cam.intrinsics)])]
            if cam.colors is not None and cam.recording_has_color:
                sensors.append(_RecordedSensor([_color_profile()]))
            return sensors

    class context:  # noqa: N801
        def load_device(self, file_name: str) -> _Device:
            if not Path(file_name).exists():
                raise RuntimeError(f"Failed to open .db3 file '{file_name}': File does not exist!")
            cam.recording, cam.cursor = file_name, 0
            cam.loads += 1
            return _Device()

    class syncer:  # noqa: N801
        def __init__(self, queue_size: int = 1) -> None:
            pass

        def try_wait_for_frames(self, timeout_ms: int = 5000) -> tuple[bool, Any]:
            if cam.cursor >= len(cam.frames):
                return False, None
            cam.cursor += 1
            return True, _Frameset(cam, cam.cursor - 1)

        def poll_for_frames(self) -> Any:
            return self.try_wait_for_frames(0)[1]

    class _Profile:
        def get_device(self) -> _Device:
            return _Device()

        def get_stream(self, s: stream) -> _VideoProfile:
            return _color_profile() if s is stream.color else _VideoProfile(stream.depth, cam.intrinsics)

    class pipeline:  # noqa: N801
        def start(self, cfg: config) -> _Profile:
            if cam.start_error is not None:
                raise cam.start_error
            return _Profile()

        def _take(self) -> _Frameset:
            if cam.cursor >= len(cam.frames):
                cam.cursor = 0  # a live camera never runs out
            k = cam.cursor
            cam.cursor += 1
            return _Frameset(cam, k)

        def wait_for_frames(self, timeout_ms: int = 5000) -> _Frameset:
            cam.waits += 1
            return self._take()

        def poll_for_frames(self) -> _Frameset:
            cam.polls += 1
            return self._take()

        def stop(self) -> None:
            cam.stopped += 1

    class align:  # noqa: N801
        def __init__(self, to: stream) -> None:
            assert to is stream.color

        def process(self, frames: _Frameset) -> _Frameset:
            cam.aligned += 1
            return frames

    rs.config, rs.pipeline, rs.align = config, pipeline, align  # type: ignore[attr-defined]
    rs.context, rs.syncer = context, syncer  # type: ignore[attr-defined]
    rs.stream, rs.format, rs.distortion = stream, format, distortion  # type: ignore[attr-defined]
    rs.playback_status = playback_status  # type: ignore[attr-defined]
    return rs


def install(monkeypatch: Any, cam: FakeCamera) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", make_module(cam))
