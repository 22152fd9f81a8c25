"""Robot-side injectable effects (off by default) and their catalog.

The catalog maps the names recipes and the model-gap workflow use to the effect classes::

    effects:
      joint_compliance: {joints: [2, 3], compliance_rad_per_nm: [2.0e-6, 3.0e-6]}
      backlash:         {joints: [1], width_rad: [2.0e-4]}

Sensor-side effects (depth scale/bias, latency, hand-eye, placement) live with the sensor models.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from plugins.robot.effects.base import CONTEXT_FIELDS, ParamSpec, RobotEffect, SampleContext
from plugins.robot.effects.geometric import BaseFrameError, GeometricErrors, JointOffset, LinkLength, ToolOffsetError
from plugins.robot.effects.joint_effects import Backlash, EncoderEccentricity, JointCompliance
from plugins.robot.effects.thermal import TemperatureExpansion, ThermalDrift

CATALOG: dict[str, type[RobotEffect]] = {
    cls.catalog_name: cls
    for cls in (
        GeometricErrors,
        JointOffset,
        LinkLength,
        BaseFrameError,
        ToolOffsetError,
        JointCompliance,
        Backlash,
        EncoderEccentricity,
        ThermalDrift,
        TemperatureExpansion,
    )
}


def effect_from_config(name: str, params: Mapping[str, Any] | None = None) -> RobotEffect:
    """Build a catalog effect from recipe-style parameters (lists become tuples)."""
    if name not in CATALOG:
        from difflib import get_close_matches

        close = get_close_matches(name, list(CATALOG), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown robot effect {name!r}{hint} Known: {', '.join(sorted(CATALOG))}")
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in (params or {}).items()}
    if name == "geometric_errors" and "offsets" in kw and isinstance(kw["offsets"], Mapping):
        return GeometricErrors.from_dict(dict(kw["offsets"]))
    try:
        return CATALOG[name](**kw)
    except TypeError as e:
        raise ValueError(f"robot effect {name!r}: {e}") from None


def effects_from_config(config: Mapping[str, Mapping[str, Any]] | None) -> list[RobotEffect]:
    """All effects of a recipe's ``effects:`` mapping, in order."""
    return [effect_from_config(k, v) for k, v in (config or {}).items()]


__all__ = [
    "CATALOG",
    "CONTEXT_FIELDS",
    "Backlash",
    "BaseFrameError",
    "EncoderEccentricity",
    "GeometricErrors",
    "JointCompliance",
    "JointOffset",
    "LinkLength",
    "ParamSpec",
    "RobotEffect",
    "SampleContext",
    "TemperatureExpansion",
    "ThermalDrift",
    "ToolOffsetError",
    "effect_from_config",
    "effects_from_config",
]
