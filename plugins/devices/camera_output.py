"""One depth-camera frame and how a camera stage publishes it (the camera contract's outputs).

Every depth-camera adapter (RealSense, file camera) turns what it read into a :class:`CameraFrame`
and calls :func:`publish_capture`: the cloud (camera frame, metres) goes out on ``cloud`` and is the
``capture`` reply; when the frame has a depth image and intrinsics, ``depth`` (32FC1, metres, NaN
invalid) and ``camera_info`` go out too. ``camera_info`` carries the pinhole K; ``D`` holds the
librealsense coefficients (k1 k2 p1 p2 k3) with ``distortion_model`` ``plumb_bob`` for none and
brown_conrady (OpenCV's forward model), ``inverse_brown_conrady`` for RealSense's inverse model.

:class:`DepthCameraAdapter` is the base of the adapter stages (the camera contract and ``frames``);
:class:`DepthCameraParams` are the parameters every adapter shares: ``frame_id``, the output
switches (``publish_cloud``, ``publish_depth``, ``decimate``, ``cloud_decimate``: :func:`publish_capture`)
and where the
camera is: ``T_parent_cam`` in ``parent_frame`` (``world``
for a fixed camera, ``tcp`` for one on the flange: the hand-eye transform), published on ``frames``
at set-up and with every capture so that a recording shows the cloud in the cell's 3D view. The
default, identity in ``world``, says "not given" and puts the camera at the world origin.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar, TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, model_validator

from engine.messages import CameraInfo, FrameTransforms, Image, PointCloud, Transform
from engine.stage import Stage, StageContext, StageParams
from plugins.camera.pinhole import CameraModel
from plugins.interfaces import CAMERA_OUTPUTS, CAMERA_SERVICES
from plugins.params import PoseSpec


class DepthCameraParams(StageParams):
    """The camera's mount and what its captures publish, shared by the depth-camera adapters."""

    frame_id: str = Field("camera", description="frame of the published cloud")
    parent_frame: str = Field(
        "world", min_length=1, description="frame the camera is mounted in (world: fixed; tcp: on the flange)"
    )
    T_parent_cam: PoseSpec = Field(
        default_factory=PoseSpec, description="camera pose in parent_frame (mount or hand-eye), published on frames"
    )
    publish_cloud: bool = Field(True, description="also publish each capture on the cloud port")
    publish_depth: bool = Field(True, description="publish the depth image and camera_info when the frame has them")
    decimate: int = Field(1, ge=1, le=64, description="keep every n-th valid point (smaller clouds)")
    cloud_decimate: int = Field(
        1, ge=1, le=64, description="the cloud port shows every n-th point of each capture (the reply keeps all)"
    )

    @model_validator(mode="after")
    def _mount_frames(self) -> DepthCameraParams:
        if self.parent_frame == self.frame_id:
            raise ValueError(f"parent_frame must differ from the camera frame {self.frame_id!r}")
        return self


class DepthCameraAdapter(Stage):
    """Base of the depth-camera adapters (``realsense_camera``, ``file_camera``): the camera contract
    of :mod:`plugins.interfaces` (role, the ``capture`` service, the camera outputs) and ``frames``
    for the mount (:func:`publish_mount`, :func:`publish_capture`)."""

    role = "sensor"
    services: ClassVar = CAMERA_SERVICES
    outputs: ClassVar = {**CAMERA_OUTPUTS, "frames": FrameTransforms}
    Params = DepthCameraParams


def publish_mount(ctx: StageContext, params: DepthCameraParams) -> None:
    """Publish ``parent_frame -> frame_id`` (``T_parent_cam``) on ``frames``, stamped now."""
    now = ctx.clock.now_ns()
    edge = Transform(
        frame_id=params.parent_frame, child_frame_id=params.frame_id, T=params.T_parent_cam.T(), stamp_ns=now
    )
    ctx.publish("frames", FrameTransforms(stamp_ns=now, transforms=[edge]))


@dataclass
class CameraFrame:
    """Points (N, 3) in the camera frame and what else the source knows about the frame."""

    points: NDArray[np.floating]
    normals: NDArray[np.floating] | None = None
    colors: NDArray[np.uint8] | None = None
    depth_m: NDArray[np.float32] | None = None  # (H, W), NaN invalid
    intrinsics: CameraModel | None = None
    source: str = ""  # file name or device frame, for messages


_Points = TypeVar("_Points", CameraFrame, PointCloud)


def thinned(points: _Points, n: int) -> _Points:
    """Every *n*-th point of a :class:`CameraFrame` or a PointCloud (with its normal and colour), all
    else kept: smaller clouds at a fixed, seed-free rule. A camera publishes such a copy on ``cloud``
    to show a capture without recording all of it twice (the reply has it)."""
    if n <= 1:
        return points
    return replace(
        points,
        points=points.points[::n],
        normals=None if points.normals is None else points.normals[::n],
        colors=None if points.colors is None else points.colors[::n],
    )


def camera_info(camera: CameraModel, frame_id: str) -> CameraInfo:
    """The ``CameraInfo`` of a depth frame (stamped when published)."""
    return camera.to_camera_info(frame_id)


def publish_capture(ctx: StageContext, params: DepthCameraParams, frame: CameraFrame) -> PointCloud:
    """Publish a capture as every depth-camera adapter does: the mount on ``frames``, then every
    ``decimate``-th point of *frame* as the cloud, on ``cloud`` every ``cloud_decimate``-th of those
    (``publish_cloud``), and the depth image and ``camera_info`` when the frame has them
    (``publish_depth``); returns the cloud (the ``capture`` reply)."""
    publish_mount(ctx, params)
    frame = thinned(frame, params.decimate)
    dtype, frame_id = np.float32, params.frame_id
    cloud = PointCloud(
        points=np.ascontiguousarray(frame.points, dtype=dtype),
        normals=None if frame.normals is None else np.ascontiguousarray(frame.normals, dtype=dtype),
        colors=frame.colors,
        frame_id=frame_id,
    )
    if params.publish_depth and frame.depth_m is not None and frame.intrinsics is not None:
        ctx.publish("depth", Image(data=frame.depth_m, encoding="32FC1", frame_id=frame_id))
        ctx.publish("camera_info", camera_info(frame.intrinsics, frame_id))
    if params.publish_cloud:
        ctx.publish("cloud", thinned(cloud, params.cloud_decimate))
    return cloud
