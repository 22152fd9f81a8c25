"""Measurement-side effects a model-gap fit can name: stream latency and range scale / bias.

The robot-side effects (:mod:`plugins.robot.effects`) change where the tool really is; these
change what the external sensor *reports* about it. They are fittable: each is a frozen dataclass
with :meth:`param_specs`, :meth:`pack` / :meth:`unpack` like a :class:`RobotEffect`, and a
measurement law that the simulator applies (hidden truth) and the model-gap workflow fits.

``time_latency``  the measurement stamped ``t`` shows the tool at ``t - L`` (the tracker / camera
                  stream lags the robot's joint stream; ``L < 0``: it leads). To first order in
                  ``L`` the commanded joints at the measurement are ``q(t - L) = q(t) - L qd(t)``,
                  so fitting needs the joint velocities at each sample (CSV ``qdN_deg_s``).
``depth_scale``   a ranging sensor (depth camera, laser tracker distance meter) at the origin of the
                  measurement frame reports ``r_meas = (1 + e) r``: the point moves along its ray by
                  ``e r`` (``e`` dimensionless, ``1 + e`` is the camera's ``depth_scale``).
``depth_bias``    the same sensor reports ``r_meas = r + b``: the point moves along its ray by ``b``.

Both range effects use the ray from the measurement frame's origin to the point, so they apply to
data given in the ranging sensor's own frame (CSV column ``range_mm`` declares such data, see
``docs/model_gap.md``). The same laws are those of the simulated camera
(:class:`plugins.sim.sensor_effects.CameraEffects`: ``r_meas = depth_scale * r + depth_bias_m``) and
tracker (``TrackerEffects.latency_s``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.robot.effects.base import ParamSpec

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class MeasurementEffect:
    """Base of the measurement-side effects: one scalar parameter acting at a named sensor."""

    sensor: str = "sensor"

    catalog_name: ClassVar[str] = ""
    field_name: ClassVar[str] = ""
    unit: ClassVar[str] = ""
    requires: ClassVar[tuple[str, ...]] = ()
    description: ClassVar[str] = ""

    def __post_init__(self) -> None:
        if not isinstance(self.sensor, str) or not self.sensor:
            raise ValueError(f"{self.catalog_name}: sensor must be a non-empty name")
        if not np.isfinite(self.value):
            raise ValueError(f"{self.catalog_name}: {self.field_name} must be finite, got {self.value}")

    @property
    def value(self) -> float:
        return float(getattr(self, self.field_name))

    @property
    def where(self) -> str:
        return self.sensor

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return (ParamSpec(self.field_name, self.unit, self.sensor, self.description),)

    @property
    def n_params(self) -> int:
        return 1

    def pack(self) -> F64:
        return np.array([self.value])

    def unpack(self, x: ArrayLike) -> Self:
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.size != 1 or not np.isfinite(x[0]):
            raise ValueError(f"{self.catalog_name} has one finite parameter, got {x}")
        return replace(self, **{self.field_name: float(x[0])})  # type: ignore[type-var]

    def param_bounds(self) -> tuple[F64, F64]:
        return np.array([-np.inf]), np.array([np.inf])

    def describe(self) -> dict:
        return {
            "name": self.catalog_name,
            "where": self.where,
            "params": {self.field_name: self.value},
            "units": {self.field_name: self.unit},
        }


@dataclass(frozen=True)
class TimeLatency(MeasurementEffect):
    """Measurement stream lag ``L`` (s) behind the joint stream: joints seen at ``q - L qd``."""

    latency_s: float = 0.0

    catalog_name: ClassVar[str] = "time_latency"
    field_name: ClassVar[str] = "latency_s"
    unit: ClassVar[str] = "s"
    requires: ClassVar[tuple[str, ...]] = ("qd",)
    description: ClassVar[str] = "the measurement at t shows the tool at t - latency"

    def joints_seen(self, q: F64, qd: F64) -> F64:
        """Commanded joints at the instant the measurement shows (first order in the latency)."""
        return np.asarray(q, dtype=float) - self.latency_s * np.asarray(qd, dtype=float)


@dataclass(frozen=True)
class DepthScale(MeasurementEffect):
    """Range scale error ``e``: ``r_meas = (1 + e) r`` along each ray from the sensor origin."""

    scale_error: float = 0.0

    catalog_name: ClassVar[str] = "depth_scale"
    field_name: ClassVar[str] = "scale_error"
    unit: ClassVar[str] = "1"
    requires: ClassVar[tuple[str, ...]] = ("range",)
    description: ClassVar[str] = "relative range error (depth_scale - 1)"


@dataclass(frozen=True)
class DepthBias(MeasurementEffect):
    """Range bias ``b`` (m): ``r_meas = r + b`` along each ray from the sensor origin."""

    bias_m: float = 0.0

    catalog_name: ClassVar[str] = "depth_bias"
    field_name: ClassVar[str] = "bias_m"
    unit: ClassVar[str] = "m"
    requires: ClassVar[tuple[str, ...]] = ("range",)
    description: ClassVar[str] = "constant range offset along the ray"


MEASUREMENT_CATALOG: dict[str, type[MeasurementEffect]] = {
    cls.catalog_name: cls for cls in (TimeLatency, DepthScale, DepthBias)
}


def apply_range_distortion(p: ArrayLike, scale_error: float = 0.0, bias_m: float = 0.0) -> F64:
    """Points ``(N, 3)`` as a ranging sensor at the origin reports them: ``((1 + e) r + b) u``."""
    P = np.asarray(p, dtype=float)
    r = np.linalg.norm(P, axis=-1, keepdims=True)
    if np.any(r <= 0):
        raise ValueError("a point sits at the ranging sensor's origin: its ray is undefined")
    return P * (1.0 + scale_error + bias_m / r)


def range_distortion_jacobian(p: ArrayLike, scale_error: float = 0.0, bias_m: float = 0.0) -> F64:
    """``(N, 3, 3)`` derivative of :func:`apply_range_distortion` with respect to the true point."""
    P = np.asarray(p, dtype=float).reshape(-1, 3)
    r = np.linalg.norm(P, axis=1)
    u = P / r[:, None]
    uu = u[:, :, None] * u[:, None, :]
    radial = 1.0 + scale_error
    tangential = 1.0 + scale_error + bias_m / r
    return radial * uu + tangential[:, None, None] * (np.eye(3) - uu)


__all__ = [
    "MEASUREMENT_CATALOG",
    "DepthBias",
    "DepthScale",
    "MeasurementEffect",
    "TimeLatency",
    "apply_range_distortion",
    "range_distortion_jacobian",
]
