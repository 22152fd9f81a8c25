"""The one camera type of vgr: pinhole intrinsics and a lens distortion model.

``CameraModel`` is what ``vgr calibrate intrinsics`` produces, what a depth camera (real or
simulated) reports, and what board poses, rendering, depth deprojection and hand-eye steps consume.
Projection and undistortion are OpenCV's (``cv2.projectPoints``, ``cv2.undistortPointsIter``, their
``cv2.fisheye`` twins); depth images are deprojected by plugins/camera/depth_projection.py. This
module holds the numbers, names the models, and converts to the ``CameraInfo`` message and a JSON
document.

Distortion models (``model`` -> coefficients ``D`` in OpenCV's order -> ROS / Foxglove name):

* ``standard``: ``k1, k2, p1, p2, k3`` -> ``plumb_bob`` (Brown-Conrady, 5 coefficients);
* ``rational``: ``k1, k2, p1, p2, k3, k4, k5, k6`` -> ``rational_polynomial`` (OpenCV's
  ``CALIB_RATIONAL_MODEL``: radial ``(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)``);
* ``fisheye``: ``k1, k2, k3, k4`` -> ``equidistant`` (Kannala-Brandt, ``cv2.fisheye``;
  librealsense's ``kannala_brandt4``);
* ``inverse_brown_conrady``: ``k1, k2, p1, p2, k3`` -> ``inverse_brown_conrady``, the model some
  RealSense streams report (librealsense ``rs2_distortion``): the coefficients map distorted to
  undistorted coordinates, so OpenCV cannot project through it; it deprojects (``normalised``).

librealsense's ``none`` and ``brown_conrady`` are ``standard`` (zero coefficients for ``none``).

Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
DistortionModel = Literal["standard", "rational", "fisheye", "inverse_brown_conrady"]

__all__ = ["CAMERA_FORMAT", "DISTORTION", "CameraModel", "DistortionModel", "realsense_undistort"]

CAMERA_FORMAT = "vgr.camera_calibration/1"

#: model -> (number of coefficients, their names, ROS / Foxglove distortion_model)
DISTORTION: dict[str, tuple[int, tuple[str, ...], str]] = {
    "standard": (5, ("k1", "k2", "p1", "p2", "k3"), "plumb_bob"),
    "rational": (8, ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), "rational_polynomial"),
    "fisheye": (4, ("k1", "k2", "k3", "k4"), "equidistant"),
    "inverse_brown_conrady": (5, ("k1", "k2", "p1", "p2", "k3"), "inverse_brown_conrady"),
}
_ROS_TO_MODEL = {ros: m for m, (_, _, ros) in DISTORTION.items()}
_UNDISTORT_CRITERIA = (3, 200, 1e-12)  # cv2.TERM_CRITERIA_COUNT | EPS: converge to ~1e-9 px
REALSENSE_UNDISTORT_ITERATIONS = 10  # librealsense's fixed count in rs2_deproject_pixel_to_point


def realsense_undistort(
    x0: NDArray[np.float64], y0: NDArray[np.float64], D: ArrayLike, *, inverse: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Undistorted normalised coordinates of distorted ones ``(x0, y0)`` (any equal shapes) by
    librealsense's fixed 10-iteration scheme (``rs2_deproject_pixel_to_point``, brown_conrady or, with
    *inverse*, inverse_brown_conrady), vectorised: the numbers the camera's own SDK gives."""
    k1, k2, p1, p2, k3 = (float(c) for c in np.asarray(D, dtype=float).ravel())
    x, y = x0.copy(), y0.copy()
    for _ in range(REALSENSE_UNDISTORT_ITERATIONS):
        r2 = x * x + y * y
        icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        xq, yq = (x / icdist, y / icdist) if inverse else (x, y)
        dx = 2 * p1 * xq * yq + p2 * (r2 + 2 * xq * xq)
        dy = 2 * p2 * xq * yq + p1 * (r2 + 2 * yq * yq)
        x, y = (x0 - dx) * icdist, (y0 - dy) * icdist
    return x, y


def check_image_size(width: float, height: float) -> None:
    """Raise ValueError unless the image size is positive and integral (pixels)."""
    if int(width) != width or int(height) != height:
        raise ValueError(f"image size must be integral, got {width} x {height}")
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width} x {height}")


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Intrinsics ``K`` (3x3, pixels), distortion ``D`` of ``model``, image ``width`` x ``height``.

    ``extra`` carries what a calibration adds to the numbers (RMS, per-image RMS, 1-sigma values),
    saved with the camera and ignored by the geometry."""

    width: int
    height: int
    K: F64
    D: F64
    model: DistortionModel = "standard"
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.model not in DISTORTION:
            raise ValueError(f"unknown distortion model {self.model!r}: use {', '.join(DISTORTION)}")
        K = np.asarray(self.K, dtype=float)
        n = DISTORTION[self.model][0]
        D = np.asarray(self.D, dtype=float).ravel()
        if D.size == 0:
            D = np.zeros(n)
        if K.shape != (3, 3):
            raise ValueError(f"K must be a 3x3 camera matrix, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise ValueError(f"intrinsics must be finite, got K = {K.tolist()}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        if D.size != n or not np.all(np.isfinite(D)):
            raise ValueError(f"the {self.model} model has {n} finite distortion coefficients, got {D.tolist()}")
        check_image_size(self.width, self.height)
        if abs(K[0, 1]) > 1e-9 or abs(K[1, 0]) > 1e-9 or np.any(np.abs(K[2] - (0, 0, 1)) > 1e-9):
            raise ValueError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def pinhole(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        D: ArrayLike = (),
        model: DistortionModel = "standard",
    ) -> CameraModel:
        """A camera from its focal lengths and principal point in pixels (zero distortion unless
        *D* is given)."""
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(width, height, K, np.asarray(D, dtype=float), model)

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def distorted(self) -> bool:
        """True unless every distortion coefficient is zero."""
        return bool(np.any(self.D != 0.0))

    @property
    def horizontal_fov_rad(self) -> float:
        """Full horizontal field of view through the outer pixel edges, distortion ignored."""
        return math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)

    @property
    def ros_distortion_model(self) -> str:
        return DISTORTION[self.model][2]

    @property
    def coefficient_names(self) -> tuple[str, ...]:
        return DISTORTION[self.model][1]

    # ------------------------------------------------------------------ geometry

    def project(self, T_cam_target: ArrayLike, points: ArrayLike) -> F64:
        """Pixels ``(n, 2)`` of points ``(n, 3)`` given in frame ``target`` seen from pose ``T_cam_target``."""
        uv, _ = self.project_with_jacobian(T_cam_target, points, jacobian=False)
        return uv

    def project_camera_points(self, points_cam: ArrayLike) -> F64:
        """Pixels ``(n, 2)`` of points ``(n, 3)`` in the camera frame: plain pinhole arithmetic for an
        undistorted camera (the simulated depth camera's, per pixel), else :meth:`project`."""
        P = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        if self.distorted:
            return self.project(np.eye(4), P)
        return np.column_stack((self.fx * P[:, 0] / P[:, 2] + self.cx, self.fy * P[:, 1] / P[:, 2] + self.cy))

    def project_with_jacobian(
        self, T_cam_target: ArrayLike, points: ArrayLike, *, jacobian: bool = True
    ) -> tuple[F64, F64 | None]:
        """Pixels and OpenCV's Jacobian ``(2n, 10 + len(D))`` of ``cv2.projectPoints`` (columns:
        rvec 3, tvec 3, fx fy 2, cx cy 2, D) -- ``None`` for the fisheye model or ``jacobian=False``."""
        import cv2

        T = np.asarray(T_cam_target, dtype=float)
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        tvec = np.ascontiguousarray(T[:3, 3].reshape(3, 1))
        obj = np.asarray(points, dtype=float).reshape(-1, 1, 3)
        D = self.D
        if self.model == "inverse_brown_conrady":
            if self.distorted:
                raise ValueError("OpenCV cannot project through inverse_brown_conrady distortion; it only deprojects")
            D = np.zeros(5)
        if self.model == "fisheye":
            uv, _ = cv2.fisheye.projectPoints(obj, rvec, tvec, self.K, self.D)
            return uv.reshape(-1, 2).astype(float), None
        uv, J = cv2.projectPoints(obj, rvec, tvec, self.K, D)
        return uv.reshape(-1, 2).astype(float), (np.asarray(J, dtype=float) if jacobian else None)

    def normalised(self, pixels: ArrayLike) -> F64:
        """Undistorted normalised image coordinates ``(x/z, y/z)`` ``(n, 2)`` of pixels ``(n, 2)``."""
        import cv2

        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if self.model == "inverse_brown_conrady":
            x0 = (uv[:, 0, 0] - self.cx) / self.fx
            y0 = (uv[:, 0, 1] - self.cy) / self.fy
            return np.column_stack(realsense_undistort(x0, y0, self.D, inverse=True))
        if self.model == "fisheye":
            out = cv2.fisheye.undistortPoints(uv, self.K, self.D, criteria=_UNDISTORT_CRITERIA)
        else:
            out = cv2.undistortPointsIter(uv, self.K, self.D, None, None, _UNDISTORT_CRITERIA)
        return np.asarray(out, dtype=float).reshape(-1, 2)

    # ------------------------------------------------------------------ conversions

    def to_camera_info(self, frame_id: str = "camera", stamp_ns: int = 0, seq: int = 0) -> Any:
        """The ``CameraInfo`` message (foxglove.CameraCalibration) of this camera."""
        from engine.messages import CameraInfo

        return CameraInfo(
            stamp_ns=stamp_ns,
            seq=seq,
            frame_id=frame_id,
            width=self.width,
            height=self.height,
            K=self.K.copy(),
            D=self.D.copy(),
            distortion_model=self.ros_distortion_model,
        )

    @classmethod
    def from_camera_info(cls, info: Any) -> CameraModel:
        """From a ``CameraInfo`` message (plumb_bob with fewer than 5 coefficients is zero-padded)."""
        name = info.distortion_model or "plumb_bob"
        if name not in _ROS_TO_MODEL:
            raise ValueError(f"distortion model {name!r} is not one of {', '.join(_ROS_TO_MODEL)}")
        model = _ROS_TO_MODEL[name]
        D = np.zeros(DISTORTION[model][0])
        d = np.asarray(info.D, dtype=float).ravel()
        if d.size > D.size:
            raise ValueError(f"{name} has {D.size} coefficients, the message {d.size}")
        D[: d.size] = d
        return cls(int(info.width), int(info.height), np.asarray(info.K, dtype=float), D, model)  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (``format`` vgr.camera_calibration/1)."""
        from engine.plain_data import plain

        d: dict[str, Any] = {
            "format": CAMERA_FORMAT,
            "width": self.width,
            "height": self.height,
            "K": self.K,
            "distortion_model": self.ros_distortion_model,
            "model": self.model,
            "D": self.D,
            "coefficients": dict(zip(self.coefficient_names, self.D.tolist(), strict=True)),
        }
        d.update(self.extra)
        return plain(d)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CameraModel:
        """Inverse of :meth:`to_dict`; also reads a CalibrationResult whose estimate holds ``camera``."""
        if "estimate" in d and isinstance(d["estimate"], dict) and "camera" in d["estimate"]:
            d = d["estimate"]["camera"]
        missing = [k for k in ("width", "height", "K", "D") if k not in d]
        if missing:
            raise ValueError(f"a camera calibration needs {', '.join(missing)}")
        model = d.get("model") or _ROS_TO_MODEL.get(d.get("distortion_model", "plumb_bob"))
        if model is None:
            raise ValueError(f"unknown distortion_model {d.get('distortion_model')!r}")
        known = {"format", "width", "height", "K", "D", "model", "distortion_model", "coefficients"}
        extra = {k: v for k, v in d.items() if k not in known}
        return cls(
            int(d["width"]), int(d["height"]), np.asarray(d["K"], float), np.asarray(d["D"], float), model, extra
        )

    def save(self, path: str | Path) -> None:
        from engine.files import replace_text

        replace_text(Path(path), json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> CameraModel:
        """A camera from a camera JSON document or an intrinsics CalibrationResult JSON."""
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"intrinsics file {p}: cannot read it ({exc})") from None
        if not isinstance(d, dict):
            raise ValueError(f"intrinsics file {p}: not a camera calibration")
        try:
            return cls.from_dict(d)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"intrinsics file {p}: {exc}") from None
