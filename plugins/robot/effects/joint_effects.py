"""Effects that shift the joint angles: compliance under gravity, gear backlash, encoder eccentricity.

Each adds an offset to the commanded angle of the joints it names (1-based, ``joint2`` = index 2):

``JointCompliance``      ``dq_j = c_j * tau_j(q, payload)``: the joint yields in the direction of
                         the gravity torque (``RobotModel.gravity_torque``), c in rad/(N m).
``Backlash``             ``dq_j = -c dir_j * b_j / 2``: the output lags half the backlash behind the
                         approach direction (``dir_j`` = +1 after moving towards larger angles, the
                         convention ``c = +1``; ``dir_convention = -1`` for data whose direction
                         columns count the other way round: +1 after moving towards smaller angles).
``EncoderEccentricity``  ``dq_j = a_j sin(q_j) + b_j cos(q_j)``: a once-per-revolution error of an
                         eccentric joint encoder, a and b in rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from plugins.robot.effects.base import (
    F64,
    ParamSpec,
    RobotEffect,
    SampleContext,
    check_joints,
    check_joints_exist,
    joint_matrix,
)


@dataclass(frozen=True)
class JointCompliance(RobotEffect):
    """Joint deflection proportional to the gravity torque at the joint (rad per N m)."""

    joints: tuple[int, ...] = ()
    compliance_rad_per_nm: tuple[float, ...] = ()
    payload_com_tcp: tuple[float, float, float] = (0.0, 0.0, 0.0)

    catalog_name: ClassVar[str] = "joint_compliance"
    vector_fields: ClassVar[tuple[str, ...]] = ("compliance_rad_per_nm",)

    def __post_init__(self) -> None:
        check_joints(self.catalog_name, self.joints, {"compliance_rad_per_nm": self.compliance_rad_per_nm})

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(
            ParamSpec(f"compliance_joint{j}", "rad/(N m)", f"joint{j}", "deflection per N m of gravity torque")
            for j in self.joints
        )

    def validate(self, model) -> None:
        check_joints_exist(self.catalog_name, self.joints, model)
        if model.links is None:
            raise ValueError(f"joint_compliance needs link masses, and model {model.name!r} has none")

    def gravity_torque(self, model, q: F64, ctx: SampleContext) -> F64:
        payload = 0.0 if ctx.payload_kg is None else ctx.payload_kg
        return model.gravity_torque(q, payload_kg=payload, payload_com_tcp=self.payload_com_tcp)

    def joint_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        if not self.joints:
            return None
        tau = self.gravity_torque(model, q, ctx)[:, [j - 1 for j in self.joints]]
        return joint_matrix(model, self.joints, tau * np.asarray(self.compliance_rad_per_nm))


@dataclass(frozen=True)
class Backlash(RobotEffect):
    """Gear backlash: the joint sits ``-dir * width / 2`` from the commanded angle.

    ``width_rad`` is the physical play (>= 0). ``dir_convention`` says how the context's ``direction``
    counts: +1 (vgr's: +1 after moving towards larger angles) or -1 (the other way round, as some
    controllers log it); the joint always lags behind the direction it really came from.
    """

    joints: tuple[int, ...] = ()
    width_rad: tuple[float, ...] = ()
    dir_convention: int = 1

    catalog_name: ClassVar[str] = "backlash"
    requires: ClassVar[tuple[str, ...]] = ("direction",)
    vector_fields: ClassVar[tuple[str, ...]] = ("width_rad",)

    def __post_init__(self) -> None:
        check_joints(self.catalog_name, self.joints, {"width_rad": self.width_rad})
        if any(w < 0 for w in self.width_rad):
            raise ValueError(f"backlash width must be >= 0, got {self.width_rad}")
        if self.dir_convention not in (1, -1):
            raise ValueError(f"backlash dir_convention must be +1 or -1, got {self.dir_convention}")

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(
            ParamSpec(f"backlash_joint{j}", "rad", f"joint{j}", "total play; +-half applied by direction")
            for j in self.joints
        )

    def param_bounds(self) -> tuple[F64, F64]:
        return np.zeros(self.n_params), np.full(self.n_params, np.inf)

    def validate(self, model) -> None:
        check_joints_exist(self.catalog_name, self.joints, model)

    def joint_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        if not self.joints:
            return None
        self.check_context(ctx)
        d = self.dir_convention * ctx.direction[:, [j - 1 for j in self.joints]]
        return joint_matrix(model, self.joints, -0.5 * d * np.asarray(self.width_rad))


@dataclass(frozen=True)
class EncoderEccentricity(RobotEffect):
    """Once-per-revolution joint angle error ``a sin(q) + b cos(q)`` (rad)."""

    joints: tuple[int, ...] = ()
    sin_rad: tuple[float, ...] = ()
    cos_rad: tuple[float, ...] = ()

    catalog_name: ClassVar[str] = "encoder_eccentricity"
    vector_fields: ClassVar[tuple[str, ...]] = ("sin_rad", "cos_rad")

    def __post_init__(self) -> None:
        check_joints(self.catalog_name, self.joints, {"sin_rad": self.sin_rad, "cos_rad": self.cos_rad})

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(
            ParamSpec(f"ecc_{kind}_joint{j}", "rad", f"joint{j}", f"amplitude of the {kind}(q) term")
            for kind in ("sin", "cos")
            for j in self.joints
        )

    def validate(self, model) -> None:
        check_joints_exist(self.catalog_name, self.joints, model)

    def joint_offsets(self, model, q: F64, ctx: SampleContext) -> F64 | None:
        if not self.joints:
            return None
        qj = q[:, [j - 1 for j in self.joints]]
        dq = np.asarray(self.sin_rad) * np.sin(qj) + np.asarray(self.cos_rad) * np.cos(qj)
        return joint_matrix(model, self.joints, dq)
