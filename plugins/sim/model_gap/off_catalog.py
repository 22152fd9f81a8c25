"""SIMULATION ONLY: hidden effects that vgr's model-gap catalog does *not* have, and gross measurement errors.

These exist to test that the workflow is honest about what its catalog lacks (``docs/model_gap.md``,
*The honest end*): a case hiding one of them has no right name, so the right verdict is
``unexplained`` with nothing named (or only the in-catalog effects hidden with it). They are never
registered as catalog effects (no ``vgr_model_effects`` hook); the simulator applies them to the
true robot only.

* ``cross_joint_sin@jointJ~qK``: joint J's angle error follows the *sine of joint K's angle* (a cable
  or hose wound around joint K pulling on joint J: the wrist cable of issue 30, joint 6 driven by
  joint 5);
* ``cross_joint_linear@jointJ~qK``: joint J's error proportional to joint K's angle (a cable that
  stretches as joint K turns);
* ``second_harmonic@jointJ``: a twice-per-revolution error ``a sin 2q + b cos 2q`` of joint J (a
  strain-wave gear's kinematic error).

:func:`add_gross_errors` adds gross errors to a campaign's measurements (a tracker losing its line of
sight): a few rows moved by 1-5 mm in a random direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from plugins.robot.effects.base import ParamSpec, RobotEffect, joint_matrix

#: the out-of-catalog effect names the simulator knows
OFF_CATALOG = ("cross_joint_sin", "cross_joint_linear", "second_harmonic")


@dataclass(frozen=True)
class CrossJointError(RobotEffect):
    """Joint ``joint``'s angle error ``amp_rad * f(q_driver)``, ``f`` = sin (``law="sin"``) or the angle
    itself in rad (``law="linear"``). Not a catalog effect (module docstring)."""

    joint: int = 6
    driver: int = 5
    law: str = "sin"
    amp_rad: float = 0.0

    catalog_name: ClassVar[str] = "cross_joint_error (simulation only)"
    vector_fields: ClassVar[tuple[str, ...]] = ("amp_rad",)

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return (ParamSpec(f"cross_amp_joint{self.joint}", "rad", f"joint{self.joint}"),)

    def joint_offsets(self, model, q, ctx):
        x = q[:, self.driver - 1]
        f = np.sin(x) if self.law == "sin" else x
        return joint_matrix(model, (self.joint,), (self.amp_rad * f)[:, None])


@dataclass(frozen=True)
class SecondHarmonicError(RobotEffect):
    """Twice-per-revolution angle error ``sin2_rad sin 2q + cos2_rad cos 2q`` of one joint (not in the catalog)."""

    joint: int = 3
    sin2_rad: float = 0.0
    cos2_rad: float = 0.0

    catalog_name: ClassVar[str] = "second_harmonic (simulation only)"
    vector_fields: ClassVar[tuple[str, ...]] = ("sin2_rad", "cos2_rad")

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return tuple(ParamSpec(f"h2_{k}_joint{self.joint}", "rad", f"joint{self.joint}") for k in ("sin", "cos"))

    def joint_offsets(self, model, q, ctx):
        x = 2.0 * q[:, self.joint - 1]
        return joint_matrix(model, (self.joint,), (self.sin2_rad * np.sin(x) + self.cos2_rad * np.cos(x))[:, None])


def unit_effect(name: str, where: str, rng: np.random.Generator, u: float = 1e-4) -> RobotEffect:
    """The out-of-catalog effect ``name@where`` at a unit-ish size with a random sign / phase (scaled later)."""
    sign = float(rng.choice((-1.0, 1.0)))
    if name in ("cross_joint_sin", "cross_joint_linear"):
        joint, _, driver = where.partition("~")
        if not (joint.startswith("joint") and driver.startswith("q")):
            raise ValueError(f"{name}: where is jointJ~qK (joint J driven by joint K), got {where!r}")
        law = "sin" if name == "cross_joint_sin" else "linear"
        return CrossJointError(int(joint[5:]), int(driver[1:]), law, sign * u)
    if name == "second_harmonic":
        phase = rng.uniform(0, 2 * np.pi)
        return SecondHarmonicError(int(where[5:]), u * np.cos(phase), u * np.sin(phase))
    raise ValueError(f"unknown out-of-catalog effect {name!r}")


def add_gross_errors(
    positions: np.ndarray, n: int, size_m: tuple[float, float], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``(positions with n rows moved by size_m[0]..size_m[1] in random directions, the rows, ascending)``."""
    if n <= 0:
        return positions, np.zeros(0, dtype=int)
    rows = np.sort(rng.choice(len(positions), n, replace=False))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    out = positions.copy()
    out[rows] += d * rng.uniform(size_m[0], size_m[1], (n, 1))
    return out, rows
