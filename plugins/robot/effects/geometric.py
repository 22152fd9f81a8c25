"""Geometric effects: offsets of named chain parameters (DH errors, joint zero offsets, link lengths,
base frame and TCP offset errors).

All act through ``param_offsets`` on the parameters of :class:`~plugins.robot.chain.KinematicChain`
(``joint2.a``, ``joint3.theta``, ``base.tz``, ``tool.tx`` ...): metres for ``a d tx ty tz``, radians
for ``theta alpha beta rx ry rz``. Base errors act in the base frame; tool position errors in the
flange frame, tool rotation errors about the TCP axes (see :mod:`plugins.robot.conventions`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from plugins.robot.effects.base import F64, ParamSpec, RobotEffect, SampleContext, check_joints, check_joints_exist

_ANGLE_SUFFIXES = ("theta", "alpha", "beta", "rx", "ry", "rz")
FRAME_COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")


def unit_of(param_name: str) -> str:
    """``rad`` or ``m`` from a chain parameter name."""
    return "rad" if param_name.rsplit(".", 1)[-1] in _ANGLE_SUFFIXES else "m"


def _offsets_vector(model, names: tuple[str, ...], values: tuple[float, ...]) -> F64:
    out = np.zeros(len(model.param_names))
    for n, v in zip(names, values, strict=True):
        out[_index(model, n)] += v
    return out


def _index(model, name: str) -> int:
    try:
        return model.chain.index(name)
    except KeyError as e:
        raise ValueError(f"{e.args[0]} in model {model.name!r} ({model.convention})") from None


@dataclass(frozen=True)
class GeometricErrors(RobotEffect):
    """Offsets of any named chain parameters, e.g. DH errors ``{"joint2.a": 2e-4, "joint3.alpha": 1e-4}``."""

    names: tuple[str, ...] = ()
    offsets: tuple[float, ...] = ()

    catalog_name: ClassVar[str] = "geometric_errors"
    vector_fields: ClassVar[tuple[str, ...]] = ("offsets",)

    def __post_init__(self) -> None:
        if len(self.names) != len(self.offsets):
            raise ValueError(f"geometric_errors: {len(self.names)} names but {len(self.offsets)} offsets")
        if len(set(self.names)) != len(self.names):
            raise ValueError("geometric_errors: parameter names must be unique")
        if not all(np.isfinite(v) for v in self.offsets):
            raise ValueError("geometric_errors: offsets contain NaN or infinity")

    @classmethod
    def from_dict(cls, offsets: dict[str, float]) -> GeometricErrors:
        return cls(tuple(offsets), tuple(float(v) for v in offsets.values()))

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(ParamSpec(n, unit_of(n), n.split(".", 1)[0]) for n in self.names)

    def validate(self, model) -> None:
        for n in self.names:
            _index(model, n)

    def param_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        return _offsets_vector(model, self.names, self.offsets) if self.names else None


@dataclass(frozen=True)
class JointOffset(RobotEffect):
    """Zero offset of joints (rad): the ``jointN.theta`` parameters."""

    joints: tuple[int, ...] = ()
    offset_rad: tuple[float, ...] = ()

    catalog_name: ClassVar[str] = "joint_offset"
    vector_fields: ClassVar[tuple[str, ...]] = ("offset_rad",)

    def __post_init__(self) -> None:
        check_joints(self.catalog_name, self.joints, {"offset_rad": self.offset_rad})

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(ParamSpec(f"offset_joint{j}", "rad", f"joint{j}") for j in self.joints)

    def validate(self, model) -> None:
        check_joints_exist(self.catalog_name, self.joints, model)

    def param_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        names = tuple(f"joint{j}.theta" for j in self.joints)
        return _offsets_vector(model, names, self.offset_rad) if names else None


@dataclass(frozen=True)
class LinkLength(RobotEffect):
    """Length error of links (m): DH ``a`` or ``d`` of the joint; ``auto`` picks the longer nominal one."""

    joints: tuple[int, ...] = ()
    offset_m: tuple[float, ...] = ()
    component: str = "auto"

    catalog_name: ClassVar[str] = "link_length"
    vector_fields: ClassVar[tuple[str, ...]] = ("offset_m",)

    def __post_init__(self) -> None:
        check_joints(self.catalog_name, self.joints, {"offset_m": self.offset_m})
        if self.component not in ("auto", "a", "d"):
            raise ValueError(f"link_length: component must be 'auto', 'a' or 'd', got {self.component!r}")

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(ParamSpec(f"length_joint{j}", "m", f"joint{j}") for j in self.joints)

    def target_names(self, model) -> tuple[str, ...]:
        if model.convention not in ("dh", "mdh"):
            raise ValueError(f"link_length needs a dh/mdh model; {model.name!r} is {model.convention}")
        out = []
        for j in self.joints:
            if self.component != "auto":
                out.append(f"joint{j}.{self.component}")
                continue
            a = abs(model.param_values[_index(model, f"joint{j}.a")])
            d = abs(model.param_values[_index(model, f"joint{j}.d")])
            out.append(f"joint{j}.a" if a >= d else f"joint{j}.d")
        return tuple(out)

    def validate(self, model) -> None:
        check_joints_exist(self.catalog_name, self.joints, model)
        self.target_names(model)

    def param_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        return _offsets_vector(model, self.target_names(model), self.offset_m) if self.joints else None


@dataclass(frozen=True)
class _FrameError(RobotEffect):
    components: tuple[str, ...] = FRAME_COMPONENTS
    offsets: tuple[float, ...] = (0.0,) * 6

    prefix: ClassVar[str] = ""
    vector_fields: ClassVar[tuple[str, ...]] = ("offsets",)

    def __post_init__(self) -> None:
        if len(self.components) != len(self.offsets):
            raise ValueError(f"{self.catalog_name}: {len(self.components)} components, {len(self.offsets)} offsets")
        bad = [c for c in self.components if c not in FRAME_COMPONENTS]
        if bad or len(set(self.components)) != len(self.components):
            raise ValueError(f"{self.catalog_name}: components must be unique among {FRAME_COMPONENTS}, got {bad}")
        if not all(np.isfinite(v) for v in self.offsets):
            raise ValueError(f"{self.catalog_name}: offsets contain NaN or infinity")

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(
            ParamSpec(f"{self.prefix}.{c}", "m" if c.startswith("t") else "rad", self.prefix) for c in self.components
        )

    def param_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        names = tuple(f"{self.prefix}.{c}" for c in self.components)
        return _offsets_vector(model, names, self.offsets) if names else None


@dataclass(frozen=True)
class BaseFrameError(_FrameError):
    """Error of the robot's base in the world (translations in m, rotations in rad, base frame)."""

    catalog_name: ClassVar[str] = "base_frame"
    prefix: ClassVar[str] = "base"


@dataclass(frozen=True)
class ToolOffsetError(_FrameError):
    """TCP offset error: position in the flange frame (m), orientation about the TCP axes (rad)."""

    catalog_name: ClassVar[str] = "tool_offset"
    prefix: ClassVar[str] = "tool"
