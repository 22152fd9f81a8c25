"""One depth-camera frame and how a camera stage publishes it (the camera contract's outputs).

Every depth-camera adapter (RealSense, file camera) turns what it read into a :class:`CameraFrame`
and calls :func:`publish_frame`: the cloud (camera frame, metres) goes out on ``cloud`` and is the
``capture`` reply; when the frame has a depth image and intrinsics, ``depth`` (32FC1, metres, NaN
invalid) and ``camera_info`` go out too. ``camera_info`` carries the pinhole K; ``D`` holds the
librealsense coefficients (k1 k2 p1 p2 k3) with ``distortion_model`` ``plumb_bob`` for none and
brown_conrady (OpenCV's forward model), ``inverse_brown_conrady`` for RealSense's inverse model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from engine.messages import CameraInfo, Image, PointCloud
from engine.stage import StageContext
from plugins.sensors.depth_projection import DepthIntrinsics


@dataclass
class CameraFrame:
    """Points (N, 3) in the camera frame and what else the source knows about the frame."""

    points: NDArray[np.floating]
    normals: NDArray[np.floating] | None = None
    colors: NDArray[np.uint8] | None = None
    depth_m: NDArray[np.float32] | None = None  # (H, W), NaN invalid
    intrinsics: DepthIntrinsics | None = None
    source: str = ""  # file name or device frame, for messages


def keep_every(frame: CameraFrame, n: int) -> CameraFrame:
    """Every *n*-th point (with its normal and colour): smaller clouds at a fixed, seed-free rule."""
    if n <= 1:
        return frame
    return CameraFrame(
        points=frame.points[::n],
        normals=None if frame.normals is None else frame.normals[::n],
        colors=None if frame.colors is None else frame.colors[::n],
        depth_m=frame.depth_m,
        intrinsics=frame.intrinsics,
        source=frame.source,
    )


def camera_info(intr: DepthIntrinsics, frame_id: str) -> CameraInfo:
    model = "inverse_brown_conrady" if intr.model == "inverse_brown_conrady" else "plumb_bob"
    return CameraInfo(
        width=intr.width,
        height=intr.height,
        K=intr.K(),
        D=np.asarray(intr.coeffs, dtype=float),
        distortion_model=model,
        frame_id=frame_id,
    )


def publish_frame(
    ctx: StageContext, frame: CameraFrame, *, frame_id: str, publish_cloud: bool, publish_depth: bool
) -> PointCloud:
    """Publish *frame* on the camera ports; return the cloud (the ``capture`` reply)."""
    dtype = np.float32
    cloud = PointCloud(
        points=np.ascontiguousarray(frame.points, dtype=dtype),
        normals=None if frame.normals is None else np.ascontiguousarray(frame.normals, dtype=dtype),
        colors=frame.colors,
        frame_id=frame_id,
    )
    if publish_depth and frame.depth_m is not None and frame.intrinsics is not None:
        ctx.publish("depth", Image(data=frame.depth_m, encoding="32FC1", frame_id=frame_id))
        ctx.publish("camera_info", camera_info(frame.intrinsics, frame_id))
    if publish_cloud:
        ctx.publish("cloud", cloud)
    return cloud
