"""Noise models of the two measured poses of a hand-eye sample: robot T_base_tcp, camera T_cam_target.

Each pose measurement ``T~`` is the true pose ``T`` perturbed in the *decoupled* way of
:mod:`engine.transforms`: ``R~ = exp([phi]) R``, ``t~ = t + dt`` with
``dt ~ N(0, diag(trans_sigma^2))`` and ``phi ~ N(0, diag(rot_sigma^2))``, both expressed in the
pose's *parent* frame (the robot base for T_base_tcp, the camera for T_cam_target, so a camera's
larger depth error is ``trans_sigma=(sx, sy, sz_bigger)``). Sigmas are in metres and radians.

A robot noise of exactly zero means "robot poses are exact" (the robot poses are then not
estimated); camera noise must be positive.

**Per-sample camera covariances** (``NoiseModel.camera_covariances``, ``(n, 6, 6)``): each camera
measurement's own covariance of the same decoupled ``(dt, dphi)`` perturbation in the camera frame,
ordered ``(tx, ty, tz, rx, ry, rz)``, in m^2, rad^2 and m rad (off-diagonal translation-rotation
terms). A depth camera's or PnP's error is largest along the line of sight and grows with the
distance, differently for every view; a board pose's covariance from its corners
(``plugins.calibration.boards.board_pose``) is one. The solver whitens each sample's camera residual
with the inverse Cholesky factor of its own covariance (:func:`camera_whitening`); ``camera`` is
then the per-axis summary of them (:func:`camera_summary`, the median variance per axis), for what
needs one figure (reports, noise limits, the consensus' cost scale). :func:`check_camera_covariances`
refuses non-finite, non-symmetric or non-positive-definite ones, naming the sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import solve_triangular

F64 = NDArray[np.float64]

__all__ = [
    "DEFAULT_PRIOR",
    "NoiseModel",
    "PoseNoise",
    "camera_noise_from_covariances",
    "camera_summary",
    "camera_whitening",
    "check_camera_covariances",
]

SYMMETRY_TOL = 1e-6  # |C_ij - C_ji| / sqrt(C_ii C_jj) above this: not a covariance (rounded files pass)


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


@dataclass(frozen=True, eq=False)
class NoiseModel:
    """Noise of the robot pose T_base_tcp and of the camera observation T_cam_target.

    ``camera_covariances`` (optional, ``(n, 6, 6)``, module docstring): each sample's own camera
    covariance; when given it is the camera's noise, and ``camera`` is replaced by its per-axis
    summary (:func:`camera_summary`).
    """

    robot: PoseNoise
    camera: PoseNoise
    camera_covariances: F64 | None = None

    def __post_init__(self) -> None:
        if self.camera_covariances is not None:
            cov = check_camera_covariances(self.camera_covariances)
            cov.setflags(write=False)
            object.__setattr__(self, "camera_covariances", cov)
            object.__setattr__(self, "camera", camera_summary(cov))
        if self.camera.is_exact:
            raise ValueError("camera noise must be positive (an exact camera leaves nothing to estimate)")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, NoiseModel):
            return NotImplemented
        a, b = self.camera_covariances, other.camera_covariances
        same_cov = (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
        return self.robot == other.robot and self.camera == other.camera and same_cov

    def __hash__(self) -> int:
        cov = None if self.camera_covariances is None else self.camera_covariances.tobytes()
        return hash((self.robot, self.camera, cov))

    @classmethod
    def isotropic(cls, robot_deg: float, robot_mm: float, camera_deg: float, camera_mm: float) -> NoiseModel:
        """Isotropic sigmas in degrees and millimetres."""
        return cls(PoseNoise.from_deg_mm(robot_deg, robot_mm), PoseNoise.from_deg_mm(camera_deg, camera_mm))

    def with_camera_covariances(self, covariances: ArrayLike | None) -> NoiseModel:
        """The same robot noise with the camera's given per sample (None: this model's shared camera
        noise, without per-sample covariances)."""
        if covariances is None:
            return NoiseModel(self.robot, self.camera)
        return NoiseModel(self.robot, self.camera, np.asarray(covariances, dtype=float))

    def take(self, index: ArrayLike) -> NoiseModel:
        """The noise of the samples selected by ``index`` (a mask or indices; the shared noise as is)."""
        if self.camera_covariances is None:
            return self
        return NoiseModel(self.robot, self.camera, self.camera_covariances[np.asarray(index)])

    def scaled_camera(self, variance_factor: float) -> NoiseModel:
        """The camera's per-sample covariances times ``variance_factor`` (shape and per-sample scale
        kept); needs ``camera_covariances``."""
        if self.camera_covariances is None:
            raise ValueError("scaled_camera needs per-sample camera covariances")
        return NoiseModel(self.robot, self.camera, self.camera_covariances * float(variance_factor))

    def camera_sigmas_per_sample(self, n: int) -> F64:
        """``(n, 6)`` camera sigmas ``(tx, ty, tz, rx, ry, rz)`` of each sample: the square roots of
        its covariance's diagonal, or the shared per-axis sigmas."""
        if self.camera_covariances is None:
            return np.broadcast_to(self.camera.sigmas6(), (n, 6))
        if len(self.camera_covariances) != n:
            raise ValueError(f"{len(self.camera_covariances)} camera covariances for {n} samples")
        return np.sqrt(np.diagonal(self.camera_covariances, axis1=1, axis2=2))

    def describe(self) -> str:
        robot = "exact" if self.robot.is_exact else self.robot.describe()
        camera = self.camera.describe()
        if self.camera_covariances is not None:
            camera = f"per-sample covariances of {len(self.camera_covariances)} samples (median {camera})"
        return f"robot: {robot}; camera: {camera}"


#: Starting point when the noise is estimated from the data (typical industrial arm and 3D camera).
DEFAULT_PRIOR = NoiseModel.isotropic(robot_deg=0.01, robot_mm=0.1, camera_deg=0.1, camera_mm=0.5)


def _named(bad: NDArray[np.intp], names: Sequence[str] | None, limit: int = 8) -> str:
    items = [str(k) if names is None else str(names[int(k)]) for k in bad[:limit]]
    return ", ".join(items) + (f" ... ({len(bad)} in all)" if len(bad) > limit else "")


def check_camera_covariances(covariances: ArrayLike, n: int | None = None, names: Sequence[str] | None = None) -> F64:
    """Per-sample camera covariances as a checked ``(n, 6, 6)`` array (symmetrised): a ValueError
    naming the samples (by *names*, else their 0-based positions) for a wrong shape or count, a
    non-finite entry, an asymmetry beyond ``SYMMETRY_TOL`` (relative to the diagonal) or a matrix
    that is not positive definite."""
    try:
        cov = np.array(covariances, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"camera covariances cannot be read as an (n, 6, 6) array ({exc})") from None
    if cov.ndim != 3 or cov.shape[1:] != (6, 6):
        raise ValueError(f"camera covariances must be (n, 6, 6) (one 6x6 per sample), got shape {cov.shape}")
    if n is not None and len(cov) != n:
        raise ValueError(f"{len(cov)} camera covariances for {n} samples: one per sample is needed")
    if names is not None and len(names) != len(cov):
        raise ValueError(f"{len(names)} sample names for {len(cov)} camera covariances")
    bad = np.flatnonzero(~np.all(np.isfinite(cov), axis=(1, 2)))
    if bad.size:
        raise ValueError(f"camera covariance of sample(s) {_named(bad, names)}: NaN or infinity")
    d = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    asym = np.max(np.abs(cov - cov.transpose(0, 2, 1)) / np.maximum(d[:, :, None] * d[:, None, :], 1e-300), axis=(1, 2))
    bad = np.flatnonzero(asym > SYMMETRY_TOL)
    if bad.size:
        raise ValueError(
            f"camera covariance of sample(s) {_named(bad, names)}: not symmetric (|C_ij - C_ji| up to "
            f"{asym[bad].max():.2g} of sqrt(C_ii C_jj)); row-major 6x6 in (tx, ty, tz, rx, ry, rz) order is expected"
        )
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    eig = np.linalg.eigvalsh(cov)
    bad = np.flatnonzero(eig[:, 0] <= 1e-14 * np.maximum(eig[:, -1], 1e-300))
    if bad.size:
        raise ValueError(
            f"camera covariance of sample(s) {_named(bad, names)}: not positive definite (smallest "
            f"eigenvalue {eig[bad[0], 0]:.3g}, largest {eig[bad[0], -1]:.3g}); every sample needs noise on all six axes"
        )
    return cov


def camera_whitening(covariances: F64) -> F64:
    """``(n, 6, 6)`` whitening matrices ``W_i = L_i^-1`` (``C_i = L_i L_i^T``, Cholesky): ``W_i e``
    has unit covariance, and ``|W_i e|^2 = e^T C_i^-1 e`` is the sample's Mahalanobis square."""
    L = np.linalg.cholesky(covariances)
    return solve_triangular(L, np.broadcast_to(np.eye(6), L.shape), lower=True)


def camera_summary(covariances: F64) -> PoseNoise:
    """One per-axis camera noise for per-sample covariances ``(n, 6, 6)``: each axis' sigma the
    square root of the median of the samples' variances on it."""
    var = np.median(np.diagonal(np.asarray(covariances, dtype=float), axis1=1, axis2=2), axis=0)
    sd = np.sqrt(np.maximum(var, 1e-18))
    return PoseNoise(sd[3:], sd[:3])


def camera_noise_from_covariances(covariances: ArrayLike, robot: PoseNoise | None = None) -> NoiseModel:
    """A shared per-axis noise model from per-sample camera covariances ``(n, 6, 6)`` (decoupled
    ``(dt, dphi)`` in the camera frame, m and rad): each axis gets the median of the samples'
    variances (:func:`camera_summary`), losing each sample's own scale and the correlations; the
    solver takes the covariances themselves (``camera_covariances=``), which this is for callers
    that cannot pair them with their samples. ``robot`` defaults to :data:`DEFAULT_PRIOR`'s."""
    cov = np.asarray(covariances, dtype=float).reshape(-1, 6, 6)
    if len(cov) == 0 or not np.all(np.isfinite(cov)):
        raise ValueError("camera covariances must be finite 6x6 matrices, at least one")
    return NoiseModel(DEFAULT_PRIOR.robot if robot is None else robot, camera_summary(cov))
