"""Noise models of the two measured poses of a hand-eye sample: robot T_base_tcp, camera T_cam_target.

Each pose measurement ``T~`` is the true pose ``T`` perturbed in the *decoupled* way of
:mod:`engine.transforms`: ``R~ = exp([phi]) R``, ``t~ = t + dt`` with
``dt ~ N(0, diag(trans_sigma^2))`` and ``phi ~ N(0, diag(rot_sigma^2))``, both expressed in the
pose's *parent* frame (the robot base for T_base_tcp, the camera for T_cam_target, so a camera's
larger depth error is ``trans_sigma=(sx, sy, sz_bigger)``). Sigmas are in metres and radians.

A robot noise of exactly zero means "robot poses are exact" (the robot poses are then not
estimated); camera noise must be positive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]

__all__ = ["DEFAULT_PRIOR", "NoiseModel", "PoseNoise", "camera_noise_from_covariances"]


def _sigma3(x: ArrayLike, name: str) -> tuple[float, float, float]:
    a = np.broadcast_to(np.asarray(x, dtype=float), (3,))
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and >= 0, got {a}")
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True, init=False)
class PoseNoise:
    """Per-axis standard deviations of one pose measurement (rad, m), in its parent frame."""

    rot_sigma: tuple[float, float, float]
    trans_sigma: tuple[float, float, float]

    def __init__(self, rot_sigma: ArrayLike, trans_sigma: ArrayLike) -> None:
        object.__setattr__(self, "rot_sigma", _sigma3(rot_sigma, "rot_sigma"))
        object.__setattr__(self, "trans_sigma", _sigma3(trans_sigma, "trans_sigma"))
        zero = [s == 0.0 for s in (*self.rot_sigma, *self.trans_sigma)]
        if any(zero) and not all(zero):
            raise ValueError(
                "a pose noise is either all zero (exact poses) or all positive; got "
                f"rot_sigma={self.rot_sigma}, trans_sigma={self.trans_sigma}"
            )

    @classmethod
    def from_deg_mm(cls, rot_deg: ArrayLike, trans_mm: ArrayLike) -> PoseNoise:
        """Construct from degrees and millimetres (how data sheets state them)."""
        return cls(np.deg2rad(np.asarray(rot_deg, dtype=float)), np.asarray(trans_mm, dtype=float) / 1000.0)

    @property
    def is_exact(self) -> bool:
        """True when every sigma is zero (the pose is known exactly)."""
        return all(s == 0.0 for s in (*self.rot_sigma, *self.trans_sigma))

    def sigmas6(self) -> F64:
        """Sigmas ordered like a decoupled perturbation: ``(tx, ty, tz, rx, ry, rz)``."""
        return np.array([*self.trans_sigma, *self.rot_sigma])

    def covariance(self) -> F64:
        """6x6 diagonal covariance of ``(dt, dphi)``."""
        return np.diag(self.sigmas6() ** 2)

    def scaled(self, rot_factor: float, trans_factor: float) -> PoseNoise:
        """A copy with the rotation and translation sigmas multiplied by the given factors."""
        return PoseNoise(np.asarray(self.rot_sigma) * rot_factor, np.asarray(self.trans_sigma) * trans_factor)

    def describe(self) -> str:
        r = np.rad2deg(self.rot_sigma)
        t = np.asarray(self.trans_sigma) * 1000.0
        return f"rot {np.array2string(r, precision=4)} deg, trans {np.array2string(t, precision=4)} mm"


@dataclass(frozen=True)
class NoiseModel:
    """Noise of the robot pose T_base_tcp and of the camera observation T_cam_target."""

    robot: PoseNoise
    camera: PoseNoise

    def __post_init__(self) -> None:
        if self.camera.is_exact:
            raise ValueError("camera noise must be positive (an exact camera leaves nothing to estimate)")

    @classmethod
    def isotropic(cls, robot_deg: float, robot_mm: float, camera_deg: float, camera_mm: float) -> NoiseModel:
        """Isotropic sigmas in degrees and millimetres."""
        return cls(PoseNoise.from_deg_mm(robot_deg, robot_mm), PoseNoise.from_deg_mm(camera_deg, camera_mm))

    def describe(self) -> str:
        robot = "exact" if self.robot.is_exact else self.robot.describe()
        return f"robot: {robot}; camera: {self.camera.describe()}"


#: Starting point when the noise is estimated from the data (typical industrial arm and 3D camera).
DEFAULT_PRIOR = NoiseModel.isotropic(robot_deg=0.01, robot_mm=0.1, camera_deg=0.1, camera_mm=0.5)


def camera_noise_from_covariances(covariances: ArrayLike, robot: PoseNoise | None = None) -> NoiseModel:
    """The solver's noise model from per-sample camera covariances ``(n, 6, 6)`` (decoupled
    ``(dt, dphi)`` in the camera frame, m and rad, e.g. each board pose's from its corners): the solver
    takes one per-axis camera noise for all samples, so each axis gets the median of the samples'
    variances. ``robot`` defaults to :data:`DEFAULT_PRIOR`'s."""
    cov = np.asarray(covariances, dtype=float).reshape(-1, 6, 6)
    if len(cov) == 0 or not np.all(np.isfinite(cov)):
        raise ValueError("camera covariances must be finite 6x6 matrices, at least one")
    var = np.median(np.diagonal(cov, axis1=1, axis2=2), axis=0)
    sd = np.sqrt(np.maximum(var, 1e-18))
    return NoiseModel(DEFAULT_PRIOR.robot if robot is None else robot, PoseNoise(sd[3:], sd[:3]))
