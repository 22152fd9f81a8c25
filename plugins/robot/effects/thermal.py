"""Thermal drift: chain parameters (link lengths, base height ...) that grow as the robot warms up.

Two laws:

* :class:`ThermalDrift`, first-order warm-up in time: each target parameter ``k`` is offset by
  ``s_k * (1 - exp(-t / tau))``, where ``t`` is the time since the robot started warming up
  (``SampleContext.t_s``), ``s_k`` the offset reached at thermal equilibrium and ``tau`` the time
  constant. Parameters: ``s_k`` (m or rad) and ``tau`` (s). :meth:`ThermalDrift.linear_expansion`
  builds the targets from a temperature rise and an expansion coefficient (every link length grows
  by ``alpha * dT * length``);
* :class:`TemperatureExpansion`, linear in a measured temperature: ``g_k * (T - T_ref)`` with
  ``T = SampleContext.temp_c`` (a motor or link temperature logged with each sample), ``g_k`` in m/K
  or rad/K. The reference only shifts a constant, which a geometric calibration takes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from plugins.robot.effects.base import F64, ParamSpec, RobotEffect, SampleContext
from plugins.robot.effects.geometric import _index, unit_of

ALUMINIUM_EXPANSION_PER_K = 23e-6
STEEL_EXPANSION_PER_K = 12e-6


@dataclass(frozen=True)
class ThermalDrift(RobotEffect):
    """Chain parameters drifting to ``saturation_offsets`` with time constant ``time_constant_s``."""

    names: tuple[str, ...] = ()
    saturation_offsets: tuple[float, ...] = ()
    time_constant_s: float = 1800.0

    catalog_name: ClassVar[str] = "thermal_drift"
    requires: ClassVar[tuple[str, ...]] = ("t_s",)
    vector_fields: ClassVar[tuple[str, ...]] = ("saturation_offsets", "time_constant_s")

    def __post_init__(self) -> None:
        if len(self.names) != len(self.saturation_offsets):
            raise ValueError(
                f"thermal_drift: {len(self.names)} names, {len(self.saturation_offsets)} saturation offsets"
            )
        if not all(np.isfinite(v) for v in self.saturation_offsets):
            raise ValueError("thermal_drift: saturation offsets contain NaN or infinity")
        if not (np.isfinite(self.time_constant_s) and self.time_constant_s > 0):
            raise ValueError(f"thermal_drift: time constant must be > 0 s, got {self.time_constant_s}")

    @classmethod
    def linear_expansion(
        cls,
        model,
        delta_temp_k: float,
        *,
        expansion_per_k: float = ALUMINIUM_EXPANSION_PER_K,
        time_constant_s: float = 1800.0,
        base_height_growth_m: float = 0.0,
    ) -> ThermalDrift:
        """Every non-zero DH length (``a``, ``d``) grows by ``expansion_per_k * delta_temp_k`` times itself.

        ``base_height_growth_m`` adds a drift of ``base.tz`` (a pedestal or table that expands).
        """
        names, offs = [], []
        for n, v in zip(model.param_names, model.param_values, strict=True):
            if n.startswith("joint") and n.rsplit(".", 1)[-1] in ("a", "d") and abs(v) > 1e-9:
                names.append(n)
                offs.append(float(v) * expansion_per_k * delta_temp_k)
        if base_height_growth_m:
            names.append("base.tz")
            offs.append(float(base_height_growth_m))
        return cls(tuple(names), tuple(offs), time_constant_s)

    def param_specs(self) -> tuple[ParamSpec, ...]:
        specs = [
            ParamSpec(f"drift_{n}", unit_of(n), n.split(".", 1)[0], "offset at thermal equilibrium") for n in self.names
        ]
        where = ",".join(dict.fromkeys(n.split(".", 1)[0] for n in self.names)) or "robot"
        specs.append(ParamSpec("time_constant", "s", where, "first-order warm-up time constant"))
        return tuple(specs)

    def param_bounds(self) -> tuple[F64, F64]:
        lo = np.full(self.n_params, -np.inf)
        lo[-1] = 1e-3
        return lo, np.full(self.n_params, np.inf)

    def validate(self, model) -> None:
        for n in self.names:
            _index(model, n)

    def warmup_fraction(self, t_s: F64) -> F64:
        """``1 - exp(-t / tau)`` (0 before warm-up starts)."""
        return 1.0 - np.exp(-np.clip(t_s, 0.0, None) / self.time_constant_s)

    def param_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        if not self.names:
            return None
        self.check_context(ctx)
        frac = self.warmup_fraction(ctx.t_s)
        out = np.zeros((q.shape[0], len(model.param_names)))
        for n, s in zip(self.names, self.saturation_offsets, strict=True):
            out[:, _index(model, n)] += s * frac
        return out


@dataclass(frozen=True)
class TemperatureExpansion(RobotEffect):
    """Chain parameters growing linearly with the logged temperature: ``growth_per_k * (temp_c - reference_c)``."""

    names: tuple[str, ...] = ()
    growth_per_k: tuple[float, ...] = ()
    reference_c: float = 20.0

    catalog_name: ClassVar[str] = "thermal_expansion"
    requires: ClassVar[tuple[str, ...]] = ("temp_c",)
    vector_fields: ClassVar[tuple[str, ...]] = ("growth_per_k",)

    def __post_init__(self) -> None:
        if len(self.names) != len(self.growth_per_k):
            raise ValueError(f"thermal_expansion: {len(self.names)} names, {len(self.growth_per_k)} growth values")
        if not all(np.isfinite(v) for v in self.growth_per_k):
            raise ValueError("thermal_expansion: growth values contain NaN or infinity")
        if not np.isfinite(self.reference_c):
            raise ValueError(f"thermal_expansion: reference temperature must be finite, got {self.reference_c}")

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(
            ParamSpec(f"growth_{n}", f"{unit_of(n)}/K", n.split(".", 1)[0], "growth per kelvin") for n in self.names
        )

    def validate(self, model) -> None:
        for n in self.names:
            _index(model, n)

    def param_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        if not self.names:
            return None
        self.check_context(ctx)
        dT = np.asarray(ctx.temp_c, dtype=float) - self.reference_c
        out = np.zeros((q.shape[0], len(model.param_names)))
        for n, g in zip(self.names, self.growth_per_k, strict=True):
            out[:, _index(model, n)] += g * dT
        return out
