"""``realsense_camera``: an Intel RealSense depth camera, live or from a recording (camera contract).

``capture`` takes one frame (:mod:`plugins.devices.realsense_device`), converts depth to metres with
the device depth scale, deprojects it with the stream intrinsics (:mod:`plugins.camera.depth_projection`)
into an organised cloud, and replies with its valid points in the camera frame (``camera``: the
depth camera, or the colour camera when ``color`` aligns depth to it; x right, y down, z forward).
It also publishes ``depth`` (32FC1, metres, NaN invalid), ``camera_info`` and ``cloud``, like
``sim_camera`` and ``file_camera``, and ``frames``: the mount ``parent_frame -> frame_id`` =
``T_parent_cam`` (default: identity in ``world``) at set-up and with every capture.

pyrealsense2 is an optional extra (``pip install 'vgr[realsense]'``), imported at set-up only.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field, model_validator

from engine.messages import PointCloud
from engine.stage import input_file
from plugins.camera.depth_projection import deproject_depth, normalized_rays
from plugins.devices.camera_output import (
    CameraFrame,
    DepthCameraAdapter,
    DepthCameraParams,
    publish_capture,
    publish_mount,
)
from plugins.devices.realsense_device import RealSenseConfig, RealSenseDevice
from plugins.devices.reconnect import Reconnecting
from plugins.util.sdk import import_sdk


class RealSenseCameraParams(DepthCameraParams):
    """Parameters of ``realsense_camera`` (units in names: m, s, Hz)."""

    serial: str | None = Field(None, description="camera serial number; None = the first camera found")
    recording: str | None = input_file(
        None, description="play this .db3 (or ROS1 .bag: untested with the real SDK) recording instead of a live camera"
    )
    loop: bool = Field(False, description="recording: start over after the last frame (else capture fails)")
    width: int = Field(848, ge=16, le=4096, description="live depth stream width, pixels")
    height: int = Field(480, ge=16, le=4096, description="live depth stream height, pixels")
    fps: int = Field(30, ge=1, le=300, description="live stream rate, Hz")
    color: bool = Field(False, description="stream colour and align depth to it (coloured cloud, colour frame)")
    min_depth_m: float = Field(0.1, ge=0.0, description="nearer points are dropped, m")
    max_depth_m: float = Field(3.0, gt=0.0, description="farther points are dropped, m")
    warmup_frames: int = Field(30, ge=0, le=1000, description="live: frames discarded at start (auto exposure)")
    discard_frames: int = Field(0, ge=0, le=100, description="live: extra frames dropped before each capture")
    timeout_s: float = Field(5.0, gt=0.0, le=60.0, description="longest wait for a frame, s")

    @model_validator(mode="after")
    def _range(self) -> RealSenseCameraParams:
        if self.min_depth_m >= self.max_depth_m:
            raise ValueError(f"min_depth_m ({self.min_depth_m}) must be below max_depth_m ({self.max_depth_m})")
        return self


class RealSenseCamera(DepthCameraAdapter):
    """Intel RealSense depth camera (pyrealsense2): live or .bag/.db3 playback, cloud in metres."""

    type_name = "realsense_camera"
    Params = RealSenseCameraParams

    device: RealSenseDevice | None = None

    def setup(self) -> None:
        p: RealSenseCameraParams = self.params  # type: ignore[assignment]
        rs = import_sdk("pyrealsense2", stage_type=self.type_name, extra="realsense", package="pyrealsense2")
        cfg = RealSenseConfig(
            serial=p.serial,
            recording=None if p.recording is None else str(self.ctx.input_path(p.recording)),
            width=p.width,
            height=p.height,
            fps=p.fps,
            color=p.color,
            loop=p.loop,
            warmup_frames=p.warmup_frames,
            discard_frames=p.discard_frames,
            timeout_s=p.timeout_s,
        )
        self.link: Reconnecting[RealSenseDevice] = Reconnecting(
            lambda: RealSenseDevice(rs, cfg), lambda d: d.close(), what=p.serial or "RealSense"
        )
        self.device = self.link.connect()  # (at set-up a camera that cannot open is the run's error)
        self.rays = normalized_rays(self.device.intrinsics)  # per pixel, reused for every frame
        intr = self.device.intrinsics
        self.ctx.event(
            "info",
            "camera_started",
            f"{p.recording or p.serial or 'RealSense'}: {intr.width}x{intr.height}, "
            f"depth scale {self.device.depth_scale * 1000:.4g} mm",
            depth_scale_m=self.device.depth_scale,
            model=intr.model,
        )
        publish_mount(self.ctx, p)

    def teardown(self) -> None:
        link = getattr(self, "link", None)
        if link is not None:
            link.close()
        self.device = None

    def on_request(self, service: str, request: Any) -> PointCloud:
        p: RealSenseCameraParams = self.params  # type: ignore[assignment]
        # a failed capture closes the device; a later one reopens it with back-off (plugins.devices.reconnect)
        shot = self.link.use(lambda device: device.capture())
        self.device = self.link.device
        depth = shot.depth_m
        depth[(depth < p.min_depth_m) | (depth > p.max_depth_m)] = np.nan
        organised = deproject_depth(depth, self.device.intrinsics, self.rays)
        flat = organised.reshape(-1, 3)
        keep = np.all(np.isfinite(flat), axis=1)
        frame = CameraFrame(
            points=flat[keep],
            colors=None if shot.color is None else shot.color.reshape(-1, 3)[keep],
            depth_m=depth,
            intrinsics=self.device.intrinsics,
            source=f"frame {shot.frame_number}",
        )
        return publish_capture(self.ctx, p, frame)
