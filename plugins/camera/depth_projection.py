"""Depth image -> organised point cloud in the camera frame (pinhole, optional RealSense distortion).

Camera frame: x right, y down, z forward along the optical axis (metres), as OpenCV, ROS optical
frames, librealsense and the simulated camera (plugins/sim/camera.py). Pixel (u, v) = (column, row) with integer
coordinates at pixel centres: ``x = (u - cx) / fx``, ``y = (v - cy) / fy``, point = depth * (x, y, 1).

Distortion (librealsense ``rs2_deproject_pixel_to_point``, coefficients ``k1 k2 p1 p2 k3``):
``none`` (or all-zero coefficients: the rectified depth stream of D400 cameras), ``brown_conrady``
and ``inverse_brown_conrady`` (both undone by librealsense's fixed 10-iteration scheme, reproduced
here vectorised). Fisheye models (``ftheta``, ``kannala_brandt4``) belong to tracking cameras, not
depth cameras, and are refused with a clear error.

Invalid depth (0, negative, NaN) gives NaN points, so the organised (H, W, 3) layout is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

DistortionModel = Literal["none", "brown_conrady", "inverse_brown_conrady"]
SUPPORTED_MODELS: tuple[str, ...] = ("none", "brown_conrady", "inverse_brown_conrady")
UNDISTORT_ITERATIONS = 10  # librealsense's empirically fixed count


def check_pinhole(width: float, height: float, fx: float, fy: float, cx: float, cy: float) -> None:
    """Raise ValueError unless the image size is positive and integral and fx, fy, cx, cy are finite
    with positive focal lengths (pixels)."""
    if int(width) != width or int(height) != height:
        raise ValueError(f"image size must be integral, got {width} x {height}")
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    vals = (fx, fy, cx, cy)
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"intrinsics must be finite, got fx, fy, cx, cy = {vals}")
    if fx <= 0 or fy <= 0:
        raise ValueError(f"focal lengths must be positive, got fx={fx}, fy={fy}")


def pinhole_K(fx: float, fy: float, cx: float, cy: float) -> NDArray[np.float64]:
    """The 3x3 camera matrix."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Pinhole intrinsics in pixels (OpenCV convention, pixel centres at integers) plus an optional
    librealsense distortion model: the one intrinsics type of depth cameras, real and simulated.
    (A camera calibrated from board images, with OpenCV's distortion models, is
    plugins.camera.pinhole.CameraModel.)"""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "none"
    coeffs: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        check_pinhole(self.width, self.height, self.fx, self.fy, self.cx, self.cy)
        if self.model not in SUPPORTED_MODELS:
            raise ValueError(
                f"distortion model {self.model!r} is not supported for depth deprojection "
                f"(supported: {', '.join(SUPPORTED_MODELS)}); fisheye models are for tracking cameras"
            )
        if len(self.coeffs) != 5 or not all(np.isfinite(self.coeffs)):
            raise ValueError(f"distortion coefficients must be 5 finite numbers (k1 k2 p1 p2 k3), got {self.coeffs}")

    @classmethod
    def from_K(cls, K: ArrayLike, width: int, height: int) -> PinholeIntrinsics:
        A = np.asarray(K, dtype=float)
        if A.shape != (3, 3) or not np.all(np.isfinite(A)):
            raise ValueError(f"K must be a finite 3x3 matrix, got shape {A.shape}")
        if abs(A[0, 1]) > 1e-9 or np.any(np.abs(A[2] - (0, 0, 1)) > 1e-9) or abs(A[1, 0]) > 1e-9:
            raise ValueError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {A.tolist()}")
        return cls(int(width), int(height), float(A[0, 0]), float(A[1, 1]), float(A[0, 2]), float(A[1, 2]))

    def K(self) -> NDArray[np.float64]:
        return pinhole_K(self.fx, self.fy, self.cx, self.cy)

    @property
    def distorted(self) -> bool:
        return self.model != "none" and any(c != 0.0 for c in self.coeffs)

    @property
    def horizontal_fov_rad(self) -> float:
        """Full horizontal field of view through the outer pixel edges."""
        return math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)

    def project(self, points_cam: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) camera-frame points -> (N, 2) pixel coordinates (u, v); an undistorted camera only."""
        if self.distorted:
            raise ValueError(f"project() is for an undistorted camera; this one has a {self.model} distortion")
        P = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        return np.column_stack((self.fx * P[:, 0] / P[:, 2] + self.cx, self.fy * P[:, 1] / P[:, 2] + self.cy))


def normalized_rays(intr: PinholeIntrinsics) -> NDArray[np.float64]:
    """(H, W, 2) undistorted normalised image coordinates (x, y) of every pixel."""
    u = np.arange(intr.width, dtype=float)
    v = np.arange(intr.height, dtype=float)
    x0 = np.broadcast_to((u - intr.cx) / intr.fx, (intr.height, intr.width))
    y0 = np.broadcast_to(((v - intr.cy) / intr.fy)[:, None], (intr.height, intr.width))
    if not intr.distorted:
        return np.stack([x0, y0], axis=-1)
    k1, k2, p1, p2, k3 = intr.coeffs
    x, y = x0.copy(), y0.copy()
    for _ in range(UNDISTORT_ITERATIONS):
        r2 = x * x + y * y
        icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        if intr.model == "inverse_brown_conrady":
            xq, yq = x / icdist, y / icdist
        else:  # brown_conrady
            xq, yq = x, y
        dx = 2 * p1 * xq * yq + p2 * (r2 + 2 * xq * xq)
        dy = 2 * p2 * xq * yq + p1 * (r2 + 2 * yq * yq)
        x, y = (x0 - dx) * icdist, (y0 - dy) * icdist
    return np.stack([x, y], axis=-1)


def deproject_depth(
    depth_m: ArrayLike, intr: PinholeIntrinsics, rays: NDArray[np.float64] | None = None
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
