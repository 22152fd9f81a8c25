"""An Intel RealSense depth camera (live or a recording) through pyrealsense2's pipeline API.

Owns the pipeline and turns its frames into metres: ``depth_m = z16 * depth_scale`` with the device's
depth scale (``first_depth_sensor().get_depth_scale()``; 1 mm on most D400 cameras, the recorded
value for a file), 0 -> NaN; intrinsics come from the depth stream profile, or from the colour
stream profile when depth is aligned to colour (``rs.align``).

Live: ``config.enable_device(serial)`` (optional) and ``enable_stream(depth, w, h, z16, fps)``
(+ colour rgb8 when asked). A capture drops the frame set already waiting in the pipeline
(``poll_for_frames``) and returns the next one, i.e. a frame that finished after the request.
Recording (ROS1 ``.bag`` of older librealsense releases, ROS2 ``.db3`` of recent ones): the file is
opened as a playback device (``rs.context().load_device``; the same reader as
``rs.config.enable_device_from_file``), switched to non-real-time *before* any sensor starts, and its
depth (and colour) sensors stream into an ``rs.syncer``: one frame set per capture, every frame, in
file order. (Through ``rs.pipeline`` the playback starts in real time before it can be switched,
and frames are lost or delivered stale: measured with pyrealsense2 2.59.) Only ``.db3`` playback is
tested with the real SDK; a valid ``.bag`` never was (2.59.1 cannot write one; see docs/adapters.md).

The SDK module is passed in (imported lazily by the stage), so tests can hand in a fake.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.camera.pinhole import CameraModel

RECORDING_SUFFIXES = (".bag", ".db3")
STOP_DRAIN_S = 30.0  # longest time spent reading the rest of a recording before stopping it
END_PROBE_MS = 100  # a recording whose playback stopped and whose syncer stays empty this long has ended


class RealSenseError(RuntimeError):
    """The camera or recording cannot be used; the message says what to check."""


class EndOfRecordingError(RealSenseError):
    """Every frame of a recording was played (and looping is off)."""


@dataclass(frozen=True)
class RealSenseConfig:
    serial: str | None = None
    recording: str | None = None
    width: int = 848
    height: int = 480
    fps: int = 30
    color: bool = False  # also stream colour; depth is then aligned to the colour camera
    loop: bool = False
    warmup_frames: int = 30
    discard_frames: int = 0
    timeout_s: float = 5.0


@dataclass
class RealSenseFrame:
    depth_m: NDArray[np.float32]  # (H, W) metres, NaN = no depth
    color: NDArray[np.uint8] | None  # (H, W, 3) RGB aligned with depth, or None
    frame_number: int
    timestamp_ms: float


#: librealsense distortion model (``rs2_distortion`` enum name) -> CameraModel model, coefficients used
RS_DISTORTION: dict[str, tuple[str, int]] = {
    "none": ("standard", 0),
    "brown_conrady": ("standard", 5),
    "inverse_brown_conrady": ("inverse_brown_conrady", 5),
    "kannala_brandt4": ("fisheye", 4),
}


def intrinsics_from_rs(intr: Any) -> CameraModel:
    """The camera of an ``rs.intrinsics`` (distortion model by its enum name). ``modified_brown_conrady``
    and ``ftheta`` are refused: no vgr model reproduces them."""
    name = getattr(intr.model, "name", str(intr.model).rsplit(".", 1)[-1])
    if name not in RS_DISTORTION:
        raise ValueError(
            f"the RealSense distortion model {name!r} is not supported (supported: {', '.join(RS_DISTORTION)})"
        )
    model, n = RS_DISTORTION[name]
    D = [float(c) for c in intr.coeffs][:n]
    return CameraModel.pinhole(
        int(intr.width), int(intr.height), float(intr.fx), float(intr.fy), float(intr.ppx), float(intr.ppy),
        D, model,  # type: ignore[arg-type]
    )  # fmt: skip


class RealSenseDevice:
    """A started RealSense camera or recording; ``capture()`` returns one frame in metres."""

    def __init__(self, rs: Any, cfg: RealSenseConfig) -> None:
        self.rs, self.cfg = rs, cfg
        self.pipe: Any = None  # live
        self.playback: Any = None  # recording
        self.sensors: list[Any] = []
        self.syncer: Any = None
        self.align: Any = None
        self._delivered = 0
        try:
            if cfg.recording is not None:
                self._open_recording()
            else:
                self._open_live()
        except Exception:
            self.close()
            raise

    # -- opening -------------------------------------------------------------------------------
    def _open_live(self) -> None:
        rs, cfg = self.rs, self.cfg
        config = rs.config()
        if cfg.serial:
            config.enable_device(cfg.serial)
        config.enable_stream(rs.stream.depth, cfg.width, cfg.height, rs.format.z16, cfg.fps)
        if cfg.color:
            config.enable_stream(rs.stream.color, cfg.width, cfg.height, rs.format.rgb8, cfg.fps)
        pipe = rs.pipeline()
        try:
            profile = pipe.start(config)
        except Exception as exc:
            which = f"with serial {cfg.serial}" if cfg.serial else "(any serial)"
            raise RealSenseError(
                f"cannot start a RealSense camera {which} at {cfg.width}x{cfg.height} @ {cfg.fps} fps: {exc}. "
                "Check: the camera is plugged into a USB 3 port (rs-enumerate-devices lists it), the serial, the "
                "udev rules (librealsense's 99-realsense-libusb.rules), no other program holds the camera, and "
                "that the camera supports this resolution and rate"
            ) from exc
        self.pipe = pipe
        self._set_device(profile.get_device())
        depth = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        color = profile.get_stream(rs.stream.color).as_video_stream_profile() if cfg.color else None
        self._set_intrinsics(depth, color)
        for _ in range(cfg.warmup_frames):  # auto exposure settles; the first frames are discarded
            self.pipe.wait_for_frames(int(cfg.timeout_s * 1000))

    def _open_recording(self) -> None:
        rs, cfg = self.rs, self.cfg
        path = Path(cfg.recording or "")
        if not path.is_file():
            raise RealSenseError(f"RealSense recording {path} does not exist")
        if path.suffix.lower() not in RECORDING_SUFFIXES:
            raise RealSenseError(f"{path}: a RealSense recording is a .bag or .db3 file")
        try:
            device = rs.context().load_device(str(path))
        except Exception as exc:
            raise RealSenseError(f"cannot play the RealSense recording {path}: {exc}") from exc
        self._pass_frames = 0
        self.playback = device.as_playback()
        self.playback.set_real_time(False)  # before any sensor streams: no frame is skipped
        self._set_device(device)
        wanted = {rs.stream.depth} | ({rs.stream.color} if cfg.color else set())
        found: dict[Any, Any] = {}
        self.syncer = rs.syncer(1)
        for sensor in device.query_sensors():
            profiles = [p for p in sensor.get_stream_profiles() if p.stream_type() in wanted]
            if not profiles:
                continue
            for p in profiles:
                found.setdefault(p.stream_type(), p.as_video_stream_profile())
            sensor.open(profiles)
            sensor.start(self.syncer)
            self.sensors.append(sensor)
        if rs.stream.depth not in found:
            raise RealSenseError(f"{path} has no depth stream")
        if cfg.color and rs.stream.color not in found:
            raise RealSenseError(f"{path} has no colour stream to align to (set color: false)")
        self._set_intrinsics(found[rs.stream.depth], found.get(rs.stream.color))

    def _set_device(self, device: Any) -> None:
        self.depth_scale = float(device.first_depth_sensor().get_depth_scale())
        if not np.isfinite(self.depth_scale) or self.depth_scale <= 0:
            raise RealSenseError(f"the camera reports an unusable depth scale {self.depth_scale}")

    def _set_intrinsics(self, depth_profile: Any, color_profile: Any | None) -> None:
        if color_profile is not None:
            self.align = self.rs.align(self.rs.stream.color)
            self.intrinsics = intrinsics_from_rs(color_profile.get_intrinsics())
        else:
            self.intrinsics = intrinsics_from_rs(depth_profile.get_intrinsics())

    # -- frames --------------------------------------------------------------------------------
    def _next_frameset(self) -> Any:
        timeout_ms = int(self.cfg.timeout_s * 1000)
        if self.playback is None:
            self.pipe.poll_for_frames()  # drop the frame set that was waiting: it started before the request
            for _ in range(self.cfg.discard_frames):
                self.pipe.wait_for_frames(timeout_ms)
            try:
                return self.pipe.wait_for_frames(timeout_ms)
            except Exception as exc:
                raise RealSenseError(f"no frame from the camera within {self.cfg.timeout_s:g} s: {exc}") from exc
        frames = self._recorded_frameset(timeout_ms)
        if frames is None:
            if not self.cfg.loop or self._delivered == 0:
                raise EndOfRecordingError(
                    f"every frame of {self.cfg.recording} was played ({self._delivered} frame sets; "
                    "set loop: true to start over)"
                )
            self._stop_sensors()
            self._delivered = 0
            self._open_recording()
            return self._next_frameset()
        self._delivered += 1
        return frames

    def _playback_stopped(self) -> bool:
        status = self.playback.current_status()
        return getattr(status, "name", str(status)).endswith("stopped")

    def _recorded_frameset(self, timeout_ms: int) -> Any | None:
        """The next frame set of the recording, or None when the file is at its end.

        The playback status alone is not trusted: right after the sensors start it can read
        ``stopped`` before the first frame arrives. The end is a status ``stopped`` with no frame
        waiting, once this pass has delivered a frame (or after the whole timeout).
        """
        deadline = time.monotonic() + timeout_ms / 1000.0
        while True:
            ok, frames = self.syncer.try_wait_for_frames(END_PROBE_MS)
            if ok:
                self._pass_frames += 1
                return frames
            if self._playback_stopped() and (self._pass_frames > 0 or time.monotonic() >= deadline):
                frames = self.syncer.poll_for_frames()
                return frames if frames else None
            if time.monotonic() >= deadline:
                raise RealSenseError(f"no frame from {self.cfg.recording} within {self.cfg.timeout_s:g} s")

    def capture(self) -> RealSenseFrame:
        frames = self._next_frameset()
        if self.align is not None:
            frames = self.align.process(frames)
        depth = frames.get_depth_frame()
        if not depth:
            raise RealSenseError("the frame set has no depth frame")
        z16 = np.asanyarray(depth.get_data())
        if z16.shape != (self.intrinsics.height, self.intrinsics.width):
            raise RealSenseError(
                f"depth frame is {z16.shape[1]}x{z16.shape[0]}, intrinsics say "
                f"{self.intrinsics.width}x{self.intrinsics.height}"
            )
        depth_m = z16.astype(np.float32) * np.float32(self.depth_scale)
        depth_m[z16 == 0] = np.nan
        color = None
        if self.align is not None:
            cf = frames.get_color_frame()
            if cf:
                color = np.array(np.asanyarray(cf.get_data()), dtype=np.uint8, copy=True)
        return RealSenseFrame(depth_m, color, int(depth.get_frame_number()), float(depth.get_timestamp()))

    def _stop_sensors(self) -> None:
        sensors, self.sensors = self.sensors, []
        if not sensors:
            return
        # A playback stopped mid-file can keep sensor.stop() waiting (10 s measured with pyrealsense2
        # 2.59 once an earlier playback device was released), one stopped at the end of the file
        # returns at once: read the rest of the file first (fast, not real time), for at most
        # STOP_DRAIN_S, then stop.
        deadline = time.monotonic() + STOP_DRAIN_S
        while self.syncer is not None and time.monotonic() < deadline:
            ok, _ = self.syncer.try_wait_for_frames(END_PROBE_MS)
            if not ok and self._playback_stopped():
                break
        for sensor in sensors:
            sensor.stop()
            sensor.close()

    def close(self) -> None:
        self._stop_sensors()
        pipe, self.pipe = self.pipe, None
        if pipe is not None:
            pipe.stop()
