"""Sensor-side injectable effects of the simulated cell: parameters only, every one off by default.

This module owns the *description* of the errors a real cell has on its sensor side; the camera,
tracker and cell models apply them.  Each effect is a frozen dataclass so a recipe can set it
(:meth:`SensorEffects.from_dict` takes the plain mapping a YAML recipe gives, in SI units) and a test
can read back exactly what was injected.  The solvers never see these objects: they see the sensor
data, and the truth goes to tests (and to ``truth/`` keys when the cell runs as a stage).

Effects and where they act:

* ``CameraEffects.depth_scale`` / ``depth_bias_m``: measured range along each ray
  ``r_meas = depth_scale * r + depth_bias_m`` (scale error grows linearly with distance; bias is a
  constant shift along the ray).
* ``CameraEffects.latency_s``: a frame stamped ``t`` shows the world at ``t - latency_s``.
* ``CameraEffects.hand_eye_error``: the true camera mount is ``T_true = T_nominal @ E`` where
  ``T_nominal`` is the ``T_tcp_cam`` (eye-in-hand) or ``T_world_cam`` (eye-to-hand) the solver
  believes and ``E`` the error expressed in the camera frame.
* ``SensorEffects.placement``: per part name, ``T_parent_part_true = T_parent_part_nominal @ E``
  (error expressed in the part frame).
* ``TrackerEffects``: the tracker reports at ``t`` the pose of ``t - latency_s``, with extra white
  noise on top of the sensor's own jitter and extra dropouts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from engine.transforms import T_from_rotvec, as_transform, log_so3
from plugins.sim.camera import DepthNoiseModel

__all__ = ["CameraEffects", "PoseOffset", "SensorEffects", "TrackerEffects"]


def _vec3(value: Any, name: str) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _finite(value: float, name: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def _from_mapping(cls: type, data: Mapping[str, Any], where: str) -> dict[str, Any]:
    if not isinstance(data, Mapping):
        raise TypeError(f"{where} must be a mapping, got {type(data).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = set(data) - known
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(known)}")
    return dict(data)


@dataclass(frozen=True)
class PoseOffset:
    """A rigid perturbation ``E`` (translation m, rotation vector rad), applied as ``T @ E``."""

    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_rotvec_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "translation_m", _vec3(self.translation_m, "translation_m"))
        object.__setattr__(self, "rotation_rotvec_rad", _vec3(self.rotation_rotvec_rad, "rotation_rotvec_rad"))

    @property
    def is_identity(self) -> bool:
        return not any(self.translation_m) and not any(self.rotation_rotvec_rad)

    def matrix(self) -> np.ndarray:
        """The 4x4 perturbation E."""
        return T_from_rotvec(self.rotation_rotvec_rad, self.translation_m)

    def apply(self, T_nominal: np.ndarray) -> np.ndarray:
        """The true transform ``T_nominal @ E``."""
        return as_transform(T_nominal, name="nominal transform") @ self.matrix()

    @classmethod
    def from_matrix(cls, E: np.ndarray) -> PoseOffset:
        E = as_transform(E, name="pose offset")
        return cls(tuple(E[:3, 3]), tuple(log_so3(E[:3, :3])))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "pose offset") -> PoseOffset:
        """From a recipe mapping; the rotation may also be given as ``rotation_deg`` (a rotation
        vector in degrees, easier to write than radians)."""
        data = dict(data)
        if "rotation_deg" in data:
            if "rotation_rotvec_rad" in data:
                raise ValueError(f"{where}: give rotation_deg or rotation_rotvec_rad, not both")
            data["rotation_rotvec_rad"] = tuple(math.radians(v) for v in _vec3(data.pop("rotation_deg"), where))
        return cls(**_from_mapping(cls, data, where))


@dataclass(frozen=True)
class CameraEffects:
    """Depth scale/bias, time latency and hand-eye error of the simulated camera (off by default)."""

    depth_scale: float = 1.0
    depth_bias_m: float = 0.0
    latency_s: float = 0.0
    hand_eye_error: PoseOffset = field(default_factory=PoseOffset)

    def __post_init__(self) -> None:
        if _finite(self.depth_scale, "depth_scale") <= 0:
            raise ValueError(f"depth_scale must be positive, got {self.depth_scale}")
        _finite(self.depth_bias_m, "depth_bias_m")
        if _finite(self.latency_s, "latency_s") < 0:
            raise ValueError(f"camera latency_s must be >= 0, got {self.latency_s}")
        if not isinstance(self.hand_eye_error, PoseOffset):
            raise TypeError("hand_eye_error must be a PoseOffset")

    def apply_to_noise(self, noise: DepthNoiseModel) -> DepthNoiseModel:
        """The camera's noise model with this depth scale and bias composed onto its own."""
        return replace(
            noise,
            depth_scale=noise.depth_scale * self.depth_scale,
            depth_bias_m=noise.depth_bias_m * self.depth_scale + self.depth_bias_m,
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "camera effects") -> CameraEffects:
        d = _from_mapping(cls, data, where)
        if "hand_eye_error" in d and not isinstance(d["hand_eye_error"], PoseOffset):
            d["hand_eye_error"] = PoseOffset.from_dict(d["hand_eye_error"], f"{where}.hand_eye_error")
        return cls(**d)


@dataclass(frozen=True)
class TrackerEffects:
    """Latency, extra noise and extra dropouts of the simulated Vive tracker (off by default)."""

    latency_s: float = 0.0
    extra_position_sigma_m: float = 0.0
    extra_rotation_sigma_rad: float = 0.0
    dropout_prob: float = 0.0

    def __post_init__(self) -> None:
        for name in ("latency_s", "extra_position_sigma_m", "extra_rotation_sigma_rad"):
            if _finite(getattr(self, name), name) < 0:
                raise ValueError(f"tracker {name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= _finite(self.dropout_prob, "dropout_prob") < 1.0:
            raise ValueError(f"tracker dropout_prob must be in [0, 1), got {self.dropout_prob}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "tracker effects") -> TrackerEffects:
        return cls(**_from_mapping(cls, data, where))


@dataclass(frozen=True)
class SensorEffects:
    """All sensor-side effects of one cell; ``SensorEffects()`` is the perfect cell."""

    camera: CameraEffects = field(default_factory=CameraEffects)
    placement: Mapping[str, PoseOffset] = field(default_factory=dict)  # part name -> offset
    tracker: TrackerEffects = field(default_factory=TrackerEffects)

    def __post_init__(self) -> None:
        for name, offset in self.placement.items():
            if not isinstance(offset, PoseOffset):
                raise TypeError(f"placement offset of part {name!r} must be a PoseOffset")

    def placement_of(self, part_name: str) -> PoseOffset:
        return self.placement.get(part_name, PoseOffset())

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> SensorEffects:
        """Build from a recipe mapping, e.g. ``{"camera": {"depth_scale": 1.002}, "placement":
        {"plate": {"translation_m": [0.001, 0, 0]}}, "tracker": {"latency_s": 0.01}}``."""
        if data is None:
            return cls()
        d = _from_mapping(cls, data, "sensor effects")
        camera = CameraEffects.from_dict(d.get("camera", {}), "sensor effects.camera")
        tracker = TrackerEffects.from_dict(d.get("tracker", {}), "sensor effects.tracker")
        placement_raw = d.get("placement", {})
        if not isinstance(placement_raw, Mapping):
            raise TypeError("sensor effects.placement must map part names to pose offsets")
        placement = {
            str(k): v if isinstance(v, PoseOffset) else PoseOffset.from_dict(v, f"placement.{k}")
            for k, v in placement_raw.items()
        }
        return cls(camera=camera, placement=placement, tracker=tracker)
