"""Depth image -> organised point cloud in the camera frame, through a camera's lens model.

Camera frame: x right, y down, z forward along the optical axis (metres), as OpenCV, ROS optical
frames, librealsense and the simulated camera (plugins/sim/camera.py). Pixel (u, v) = (column, row)
with integer coordinates at pixel centres: ``x = (u - cx) / fx``, ``y = (v - cy) / fy``, point =
depth * (x, y, 1) after undistortion. The camera is plugins/camera/pinhole.py's ``CameraModel``.

Undistortion: the ``standard`` (librealsense ``brown_conrady``) and ``inverse_brown_conrady`` models
are undone by librealsense's fixed 10-iteration scheme (``rs2_deproject_pixel_to_point``,
reproduced vectorised), so a RealSense cloud is the one its SDK gives; ``rational`` and ``fisheye``
by OpenCV (``CameraModel.normalised``). A depth camera with zero coefficients (the rectified depth
stream of D400 cameras) needs no undistortion at all.

Invalid depth (0, negative, NaN) gives NaN points, so the organised (H, W, 3) layout is kept.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.camera.pinhole import CameraModel, realsense_undistort


def normalized_rays(camera: CameraModel) -> NDArray[np.float64]:
    """(H, W, 2) undistorted normalised image coordinates (x, y) of every pixel."""
    u = np.arange(camera.width, dtype=float)
    v = np.arange(camera.height, dtype=float)
    x0 = np.broadcast_to((u - camera.cx) / camera.fx, (camera.height, camera.width))
    y0 = np.broadcast_to(((v - camera.cy) / camera.fy)[:, None], (camera.height, camera.width))
    if not camera.distorted:
        return np.stack([x0, y0], axis=-1)
    if camera.model in ("standard", "inverse_brown_conrady"):
        x, y = realsense_undistort(x0, y0, camera.D, inverse=camera.model == "inverse_brown_conrady")
        return np.stack([x, y], axis=-1)
    uu, vv = np.meshgrid(u, v)
    xy = camera.normalised(np.column_stack((uu.ravel(), vv.ravel())))
    return xy.reshape(camera.height, camera.width, 2)


def deproject_depth(
    depth_m: ArrayLike, intr: CameraModel, rays: NDArray[np.float64] | None = None
) -> NDArray[np.float32]:
    """Organised (H, W, 3) float32 cloud of a depth image in metres; NaN where depth is invalid.

    *rays* (from :func:`normalized_rays`) may be passed to reuse them across frames.
    """
    d = np.asarray(depth_m, dtype=np.float64)
    if d.shape != (intr.height, intr.width):
        raise ValueError(f"depth image is {d.shape[::-1]} (w, h) but the intrinsics are {intr.width}x{intr.height}")
    rays = normalized_rays(intr) if rays is None else rays
    z = np.where(np.isfinite(d) & (d > 0), d, np.nan)
    pts = np.empty((intr.height, intr.width, 3), dtype=np.float32)
    pts[..., 0] = rays[..., 0] * z
    pts[..., 1] = rays[..., 1] * z
    pts[..., 2] = z
    return pts


def valid_points(organised: NDArray[np.floating]) -> NDArray[np.floating]:
    """The finite points of an organised cloud, in row-major pixel order, as (N, 3)."""
    flat = organised.reshape(-1, 3)
    return flat[np.all(np.isfinite(flat), axis=1)]
