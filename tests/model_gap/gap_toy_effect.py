"""An effect from *outside* vgr's catalog, registered the way a third-party plugin would do it.

``encoder_second_harmonic``: a twice-per-revolution joint angle error ``a sin(2q) + b cos(2q)`` (a
strain-wave gear's kinematic error), at every joint. The module is a pluggy plugin: it implements
``vgr_model_effects`` and is loaded with ``vgr gap --plugin gap_toy_effect`` (or an entry point).
It reuses vgr's public building blocks (:class:`RobotEffect`, :class:`RobotCandidate`), as a plugin
author would.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from engine.hookspecs import hookimpl
from plugins.model_gap.effects import RobotCandidate
from plugins.robot.effects.base import ParamSpec, RobotEffect, check_joints, joint_matrix

NAME = "encoder_second_harmonic"


@dataclass(frozen=True)
class SecondHarmonic(RobotEffect):
    joints: tuple[int, ...] = ()
    sin2_rad: tuple[float, ...] = ()
    cos2_rad: tuple[float, ...] = ()

    catalog_name: ClassVar[str] = NAME
    vector_fields: ClassVar[tuple[str, ...]] = ("sin2_rad", "cos2_rad")

    def __post_init__(self) -> None:
        check_joints(NAME, self.joints, {"sin2_rad": self.sin2_rad, "cos2_rad": self.cos2_rad})

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(
            ParamSpec(f"h2_{kind}_joint{j}", "rad", f"joint{j}") for kind in ("sin", "cos") for j in self.joints
        )

    def joint_offsets(self, model, q, ctx):
        if not self.joints:
            return None
        qj = q[:, [j - 1 for j in self.joints]]
        dq = np.asarray(self.sin2_rad) * np.sin(2 * qj) + np.asarray(self.cos2_rad) * np.cos(2 * qj)
        return joint_matrix(model, self.joints, dq)


class SecondHarmonicFamily:
    """The effect family the hook returns (protocol ``plugins.model_gap.core.interfaces.EffectFamily``)."""

    name = NAME
    description = "twice-per-revolution joint error a sin(2q) + b cos(2q) (strain-wave gear)"
    requires: tuple[str, ...] = ()

    def candidates(self, problem) -> list:
        if getattr(problem, "kind", None) != "kinematic":
            return []
        out = []
        for j in range(1, problem.model.dof + 1):
            out.append(
                RobotCandidate(
                    NAME,
                    f"joint{j}",
                    SecondHarmonic((j,), (0.0,), (0.0,)),
                    (f"h2_sin_joint{j}", f"h2_cos_joint{j}"),
                    ("rad", "rad"),
                    np.eye(2),
                    np.full(2, -np.inf),
                    np.full(2, np.inf),
                    regressor=f"q{j}",
                    joint=j,
                )
            )
        return out


@hookimpl
def vgr_model_effects() -> list[type]:
    return [SecondHarmonicFamily]
