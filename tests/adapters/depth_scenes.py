"""Synthetic depth scenes with known geometry, and a RealSense recording writer (real pyrealsense2).

``plane_depth`` renders the exact depth of a plane for every pixel of a pinhole camera, so a
deprojected cloud can be checked against the plane and the pixel grid. ``write_recording`` makes
a real librealsense recording (.db3) of scripted z16 frames through ``rs.software_device`` and
``rs.recorder``, so the adapter's playback path runs against the real SDK without a camera.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plugins.camera.depth_projection import normalized_rays
from plugins.camera.pinhole import CameraModel

INTR = CameraModel.pinhole(80, 60, 70.0, 71.5, 39.7, 29.3)
PLANE_NORMAL = np.array([0.2, -0.3, -1.0]) / np.linalg.norm([0.2, -0.3, -1.0])  # facing the camera
PLANE_POINT = np.array([0.01, -0.02, 0.6])


def plane_depth(intr: CameraModel = INTR, n=PLANE_NORMAL, p0=PLANE_POINT) -> np.ndarray:
    """(H, W) depth z (m) of the plane n . p = n . p0 seen through each pixel."""
    rays = normalized_rays(intr)
    denom = n[0] * rays[..., 0] + n[1] * rays[..., 1] + n[2]
    return float(n @ p0) / denom


def plane_residual_m(points: np.ndarray, n=PLANE_NORMAL, p0=PLANE_POINT) -> np.ndarray:
    return np.abs(np.asarray(points, dtype=float) @ n - float(n @ p0))


def z16_of(depth_m: np.ndarray, scale: float) -> np.ndarray:
    return np.clip(np.round(depth_m / scale), 0, 65535).astype(np.uint16)


def write_recording(path: Path, frames: list[np.ndarray], intr: CameraModel, depth_scale: float) -> Path:
    """Record z16 *frames* with *intr* and *depth_scale* to a librealsense file (needs pyrealsense2)."""
    import pyrealsense2 as rs

    dev = rs.software_device()
    sensor = dev.add_sensor("Depth")
    ri = rs.intrinsics()
    ri.width, ri.height, ri.fx, ri.fy, ri.ppx, ri.ppy = intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy
    ri.model, ri.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid, vs.width, vs.height = rs.stream.depth, 0, 0, intr.width, intr.height
    vs.fps, vs.bpp, vs.fmt, vs.intrinsics = 30, 2, rs.format.z16, ri
    profile = sensor.add_video_stream(vs)
    sensor.add_read_only_option(rs.option.depth_units, depth_scale)
    recorder = rs.recorder(str(path), dev)
    rec_sensor = recorder.query_sensors()[0]
    queue = rs.frame_queue(len(frames) + 1)
    rec_sensor.open(rec_sensor.get_stream_profiles()[0])
    rec_sensor.start(queue)
    for i, z16 in enumerate(frames):
        f = rs.software_video_frame()
        f.pixels = np.ascontiguousarray(z16, dtype=np.uint16)
        f.stride, f.bpp, f.timestamp, f.frame_number = intr.width * 2, 2, i * 33.3, i
        f.domain = rs.timestamp_domain.system_time
        f.profile = profile.as_video_stream_profile()
        sensor.on_video_frame(f)
        queue.wait_for_frame(2000)
    rec_sensor.stop()
    rec_sensor.close()
    del recorder, rec_sensor  # the file is finalised when the recorder goes away
    return path
