"""The model-gap candidates: one catalog effect at one place, as the workflow scores and fits it.

* :class:`RobotCandidate`: a robot-side effect (:mod:`plugins.robot.effects`) at a joint, the robot,
  the base or the tool; its linear parameters map to the effect's vector by ``param_map``, a shape
  parameter (a time constant) is profiled over ``shape_grid``. ``geometric`` marks the robot's
  geometry (joint zeros, link lengths, frames, a uniform scale): the default baseline calibrates it
  and it never counts against ``max_effects``.
* :class:`BacklashCandidate`: backlash fitted with a sign (the data may count the approach direction
  the other way round), reported in the physical convention with a note.
* :class:`MeasurementCandidate`: a measurement-side effect (latency, range scale / bias).

The families that make them from a problem are in :mod:`.effects`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.core.interfaces import Design, Signature
from plugins.model_gap.problem import KinematicGapProblem
from plugins.model_gap.stored_model import effect_config
from plugins.robot import effects as fx
from plugins.robot.effects import RobotEffect
from plugins.robot.effects.measurement import MEASUREMENT_CATALOG

F64 = NDArray[np.float64]


@dataclass(eq=False)
class RobotCandidate:
    """A robot-side effect at one place; ``values`` map to the effect's vector by ``param_map``."""

    name: str
    where: str
    prototype: RobotEffect
    param_names: tuple[str, ...]
    units: tuple[str, ...]
    param_map: F64  # (effect vector size, len(param_names))
    lower: F64
    upper: F64
    shape_names: tuple[str, ...] = ()
    shape_grid: tuple[float, ...] = ()
    shape_lower: tuple[float, ...] = ()
    shape_upper: tuple[float, ...] = ()
    regressor: str = ""  # feature plotted against (q2, tau2, dir2, t_s ...)
    joint: int | None = None  # joint-space effects: the joint, for the signature's basis
    jac_floor: F64 | None = None  # lowest values at which the effect can be differentiated
    unavailable: str | None = None
    # rival effect name -> what separates the two when they explain the same part of the gap
    tie_advice: dict[str, str] = field(default_factory=dict)
    # part of the robot's geometry (a joint zero, a link length, the frames, a uniform scale): the
    # default baseline calibrates it, and it never counts against max_effects (plugins.model_gap.core.workflow)
    geometric: bool = False
    side: ClassVar[str] = "robot"

    @property
    def n_linear(self) -> int:
        return len(self.param_names) - len(self.shape_names)

    def effect(self, values: F64) -> RobotEffect:
        return self.prototype.unpack(self.param_map @ np.asarray(values, dtype=float))

    def jac_values(self, values: F64) -> F64:
        v = np.asarray(values, dtype=float)
        return v if self.jac_floor is None else np.maximum(v, self.jac_floor)

    def jac_map(self, values: F64) -> F64:
        """``d effect vector / d values`` at ``values`` (the linear ``param_map`` for most effects)."""
        return self.param_map

    def physical(self, values: F64) -> tuple[F64, str]:
        """The values in the effect's physical convention, and a note when that differs from the fit."""
        return np.asarray(values, dtype=float), ""

    def bounds(self) -> tuple[F64, F64]:
        return (
            np.concatenate([self.lower, np.asarray(self.shape_lower, float)]),
            np.concatenate([self.upper, np.asarray(self.shape_upper, float)]),
        )

    def config(self, values: F64) -> dict[str, Any]:
        return {self.prototype.catalog_name: effect_config(self.effect(values))}

    def designs(self, problem: KinematicGapProblem) -> list[Design]:
        zeros = np.zeros(self.n_linear)
        if not self.shape_names:
            return [Design(problem.robot_columns(self, zeros))]
        out = []
        for s in self.shape_grid:
            cols = problem.robot_columns(self, np.concatenate([zeros, [s]]))[:, :, : self.n_linear]
            out.append(Design(cols, {self.shape_names[0]: float(s)}))
        return out

    def signature(self, problem: KinematicGapProblem) -> Signature | None:
        feats = {f.name: f for f in problem.features()}
        x = feats.get(self.regressor)
        if x is None:
            return None
        if self.joint is not None:
            basis = problem.joint_position_jacobian()[:, :, self.joint - 1]
            return Signature(x.values, f"{x.label} ({x.unit})" if x.unit else x.label, basis, "joint error", "rad")
        if self.n_linear == 1:
            v = np.zeros(len(self.param_names))
            if self.shape_names:
                v[-1] = self.shape_grid[len(self.shape_grid) // 2]
            basis = problem.robot_columns(self, v)[:, :, 0] * problem.sigma[:, None]
            return Signature(x.values, f"{x.label} ({x.unit})", basis, self.param_names[0], self.units[0])
        return Signature(x.values, f"{x.label} ({x.unit})", None, "", "")  # type: ignore[arg-type]


#: what a negative backlash fit means (the fitted play with the approach directions as the data count them)
BACKLASH_CONVENTION_NOTE = (
    "the best fit has the other sign of vgr's convention (dir = +1 after moving towards larger angles): the "
    "data's dir columns count the approach direction the other way round (+1 after moving towards smaller "
    "angles); the play is given in the physical convention (>= 0), and the model keeps dir_convention -1 to "
    "read data that count this way"
)


@dataclass(eq=False)
class BacklashCandidate(RobotCandidate):
    """Backlash at one joint, fitted with a sign.

    The fitted value ``s`` is the play as the data's ``dir`` columns count the approach direction:
    ``dq = -dir s / 2``. ``s >= 0`` is a play ``s`` in vgr's convention; ``s < 0`` is a play ``|s|``
    with the direction counted the other way round (``Backlash.dir_convention = -1``): the same joint
    behaviour, so the effect is named either way, with its value in the physical convention and a note
    (:data:`BACKLASH_CONVENTION_NOTE`) instead of being refused as outside the physical range.
    """

    def effect(self, values: F64) -> RobotEffect:
        s = float(np.asarray(values, dtype=float)[0])
        return fx.Backlash((int(self.joint or 0),), (abs(s),), dir_convention=-1 if s < 0 else 1)

    def jac_values(self, values: F64) -> F64:
        s = float(np.asarray(values, dtype=float)[0])
        floor = 2e-6  # differentiated at a play the effect can represent (its own vector is >= 0)
        return np.array([s if abs(s) >= floor else (-floor if s < 0 else floor)])

    def jac_map(self, values: F64) -> F64:
        return self.param_map * (-1.0 if float(np.asarray(values)[0]) < 0 else 1.0)

    def physical(self, values: F64) -> tuple[F64, str]:
        v = np.asarray(values, dtype=float)
        return np.abs(v), BACKLASH_CONVENTION_NOTE if v[0] < 0 else ""


@dataclass(eq=False)
class MeasurementCandidate:
    """A measurement-side effect (latency, range scale / bias) at the data's sensor."""

    name: str
    where: str
    unavailable: str | None = None
    param_names: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    shape_names: tuple[str, ...] = ()
    lower: F64 = field(default_factory=lambda: np.array([-np.inf]))
    upper: F64 = field(default_factory=lambda: np.array([np.inf]))
    tie_advice: dict[str, str] = field(default_factory=dict)  # rival effect name -> what separates them
    side: ClassVar[str] = "measurement"

    def __post_init__(self) -> None:
        cls = MEASUREMENT_CATALOG[self.name]
        self.param_names = (cls.field_name,)
        self.units = (cls.unit,)

    def effect(self, values: F64):
        return MEASUREMENT_CATALOG[self.name](sensor=self.where, **{self.param_names[0]: float(values[0])})

    def jac_values(self, values: F64) -> F64:
        return np.asarray(values, dtype=float)

    def physical(self, values: F64) -> tuple[F64, str]:
        return np.asarray(values, dtype=float), ""

    def bounds(self) -> tuple[F64, F64]:
        return self.lower, self.upper

    def config(self, values: F64) -> dict[str, Any]:
        return {self.name: {"sensor": self.where, self.param_names[0]: float(values[0])}}

    def designs(self, problem: KinematicGapProblem) -> list[Design]:
        return [Design(problem.measurement_columns(self.name))]

    def signature(self, problem: KinematicGapProblem) -> Signature | None:
        feats = {f.name: f for f in problem.features()}
        key = "speed" if self.name == "time_latency" else "range"
        x = feats.get(key)
        if x is None:
            return None
        basis = problem.measurement_columns(self.name)[:, :, 0] * problem.sigma[:, None]
        return Signature(x.values, f"{x.label} ({x.unit})", basis, self.param_names[0], self.units[0])
