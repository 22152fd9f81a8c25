"""Input data of the TCP-by-camera calibration (seed 002): robot flange poses + TCP seen by a camera.

Frames: ``base`` (robot base), ``flange`` (robot end flange, seed's E), ``cam`` (a fixed camera,
seed's C). Sample i: the robot reports ``T_base_flange_i`` and the camera measures the TCP point
(a tip or marker on the tool) at ``p_cam_i``. Model (seed 002):

    p_cam_i = R_cam_base (R_base_flange_i p_flange_tcp + t_base_flange_i) + t_cam_base
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.calibration.pose_lsq import as_rotation_stack, finite_array

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TcpNoiseModel:
    """Measurement standard deviations (SI). ``camera_sigma_m`` per camera axis (a depth camera is
    usually worse along its z); the robot terms are optional (0 = exact robot poses)."""

    camera_sigma_m: tuple[float, float, float] = (0.3e-3, 0.3e-3, 0.3e-3)
    robot_position_sigma_m: float = 0.0
    robot_rotation_sigma_rad: float = 0.0

    def __post_init__(self) -> None:
        c = np.broadcast_to(np.asarray(self.camera_sigma_m, dtype=float), (3,))
        if not np.all(np.isfinite(c)) or np.any(c <= 0):
            raise ValueError(f"camera_sigma_m must be finite and > 0, got {self.camera_sigma_m}")
        object.__setattr__(self, "camera_sigma_m", tuple(float(v) for v in c))
        for name in ("robot_position_sigma_m", "robot_rotation_sigma_rad"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {v}")


@dataclass
class TcpCameraData:
    """N samples as arrays (SI units). Build with :meth:`from_arrays` or :meth:`from_marker_poses`."""

    T_base_flange: F64  # (N, 4, 4)
    p_cam: F64  # (N, 3) TCP point measured in the camera frame
    noise: TcpNoiseModel = field(default_factory=TcpNoiseModel)
    labels: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return int(self.p_cam.shape[0])

    @classmethod
    def from_arrays(
        cls,
        T_base_flange: ArrayLike,
        p_cam: ArrayLike,
        *,
        noise: TcpNoiseModel | None = None,
        labels: list[str] | None = None,
    ) -> TcpCameraData:
        """Validate shapes, finiteness and rotations (ValueError naming the sample otherwise)."""
        P = finite_array("p_cam", p_cam, (None, 3))
        n = P.shape[0]
        T = finite_array("T_base_flange", T_base_flange, (n, 4, 4)).copy()
        for i, Ti in enumerate(T):
            if not np.allclose(Ti[3], (0, 0, 0, 1), atol=1e-9):
                raise ValueError(f"T_base_flange[{i}] last row must be [0, 0, 0, 1], got {Ti[3]}")
        T[:, :3, :3], dev = as_rotation_stack("T_base_flange rotation", T[:, :3, :3])
        notes = []
        if dev > 1e-6:
            notes.append(f"flange rotations deviated from orthonormal by up to {dev:.1e}; re-orthonormalised")
        return cls(
            T,
            P,
            noise or TcpNoiseModel(),
            list(labels) if labels is not None else [f"S{i + 1}" for i in range(n)],
            notes,
        )

    @classmethod
    def from_marker_poses(
        cls, T_base_flange: ArrayLike, T_cam_marker: ArrayLike, *, noise: TcpNoiseModel | None = None
    ) -> TcpCameraData:
        """Samples from full marker poses (e.g. a hand-eye data set): only the marker origin is used."""
        Tm = finite_array("T_cam_marker", T_cam_marker, (None, 4, 4))
        return cls.from_arrays(T_base_flange, Tm[:, :3, 3], noise=noise)
