"""The contract every robot-side injectable effect follows, and the per-sample context it may use.

An effect turns the nominal robot into the "true" one. It acts in one (or both) of two places:

* ``joint_offsets``: added to the commanded joint angles (backlash, encoder eccentricity, compliance):
  ``q_actual = q_cmd + sum(joint offsets)``;
* ``param_offsets``: added to the chain parameters (DH errors, base/tool errors, thermal growth):
  ``values_actual = values_nominal + sum(param offsets)``, per sample if they vary with time.

All offsets are evaluated at the commanded configuration and the nominal model (first order: the
offsets are micro-radians to millimetres, their cross-effects are far below any sensor's noise).

Every effect is a frozen dataclass whose fields are its parameters (off by default: zero magnitude
or no joints), declares them with :class:`ParamSpec` (name, unit, where it acts), and can be fitted:
``pack()`` gives the parameter vector, ``unpack(x)`` a copy with new values, ``param_bounds()`` the
box a least-squares solver should respect. Structural fields (which joints, which components)
are not part of the vector. Ground truth lives in these objects; solvers only ever see data.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, ClassVar, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from plugins.robot.kinematics import RobotModel

F64 = NDArray[np.float64]
CONTEXT_FIELDS = ("t_s", "direction", "temp_c", "payload_kg")


@dataclass(frozen=True)
class ParamSpec:
    """One fittable parameter: ``name`` (unique in its effect), ``unit``, ``where`` it acts."""

    name: str
    unit: str
    where: str
    description: str = ""


@dataclass(frozen=True)
class SampleContext:
    """Per-sample conditions an effect may depend on (all optional; SI units).

    ``t_s`` (N,) seconds since the robot started warming up; ``direction`` (N, n) approach direction
    of each joint (+1 when the joint last moved towards larger angles, -1 otherwise); ``temp_c``
    (N,) ambient/joint temperature in deg C; ``payload_kg`` (N,) mass carried at the TCP.
    """

    t_s: F64 | None = None
    direction: F64 | None = None
    temp_c: F64 | None = None
    payload_kg: F64 | None = None

    def for_samples(self, n_samples: int, n_joints: int) -> SampleContext:
        """Broadcast scalars / single rows to ``n_samples`` and validate; raise ValueError if bad."""
        out: dict[str, F64 | None] = {}
        for name in CONTEXT_FIELDS:
            v = getattr(self, name)
            if v is None:
                out[name] = None
                continue
            a = np.asarray(v, dtype=float)
            shape = (n_samples, n_joints) if name == "direction" else (n_samples,)
            try:
                a = np.broadcast_to(a, shape).copy()
            except ValueError:
                raise ValueError(f"context {name} must broadcast to {shape}, got shape {a.shape}") from None
            if not np.all(np.isfinite(a)):
                raise ValueError(f"context {name} contains NaN or infinity")
            if name == "direction" and not np.all(np.isin(a, (-1.0, 1.0))):
                raise ValueError("context direction must be +1 or -1 for every joint")
            if name == "payload_kg" and np.any(a < 0):
                raise ValueError("context payload_kg must be >= 0")
            out[name] = a
        return SampleContext(**out)


class RobotEffect(ABC):
    """Base class of the robot-side effects (see the module docstring)."""

    #: catalog name used by recipes and the model-gap workflow (``joint_compliance`` ...)
    catalog_name: ClassVar[str] = ""
    #: context fields the effect needs (a clear error names the missing one)
    requires: ClassVar[tuple[str, ...]] = ()
    #: dataclass fields that hold the parameter vector, in ``pack`` order
    vector_fields: ClassVar[tuple[str, ...]] = ()

    # --------------------------------------------------------------------- parameters

    @abstractmethod
    def param_specs(self) -> tuple[ParamSpec, ...]:
        """Declaration of the fittable parameters, in ``pack`` order."""

    def pack(self) -> F64:
        """The parameter vector (SI units)."""
        parts = [np.asarray(getattr(self, f), dtype=float).reshape(-1) for f in self.vector_fields]
        return np.concatenate(parts) if parts else np.zeros(0)

    def unpack(self, x: ArrayLike) -> Self:
        """A copy of this effect with the parameter vector ``x``."""
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.size != self.n_params:
            raise ValueError(f"{self.catalog_name} has {self.n_params} parameters, got {x.size}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{self.catalog_name}: parameter vector contains NaN or infinity")
        kw: dict[str, Any] = {}
        k = 0
        for f in self.vector_fields:
            cur = getattr(self, f)
            if np.ndim(cur) == 0:
                kw[f] = float(x[k])
                k += 1
            else:
                m = len(cur)
                kw[f] = tuple(float(v) for v in x[k : k + m])
                k += m
        return replace(self, **kw)  # type: ignore[type-var]

    @property
    def n_params(self) -> int:
        return len(self.param_specs())

    def param_bounds(self) -> tuple[F64, F64]:
        """Lower and upper bounds of the parameter vector (default: unbounded)."""
        return np.full(self.n_params, -np.inf), np.full(self.n_params, np.inf)

    @property
    def where(self) -> str:
        """Where the effect acts, e.g. ``joint2`` or ``joint2,joint3`` or ``tool``."""
        places = dict.fromkeys(w for s in self.param_specs() for w in s.where.split(","))
        return ",".join(places)

    def describe(self) -> dict[str, Any]:
        """JSON-ready description: catalog name, where, parameters with units (for truth records)."""
        x = self.pack()
        return {
            "name": self.catalog_name,
            "where": self.where,
            "params": {s.name: float(v) for s, v in zip(self.param_specs(), x, strict=True)},
            "units": {s.name: s.unit for s in self.param_specs()},
            "structure": {
                f.name: getattr(self, f.name)
                for f in fields(self)
                if f.name not in self.vector_fields  # type: ignore[arg-type]
            },
        }

    # --------------------------------------------------------------------- behaviour

    def validate(self, model: RobotModel) -> None:  # noqa: B027  (optional hook)
        """Raise ValueError when the effect does not fit ``model`` (unknown joint or parameter)."""

    def joint_offsets(self, model: RobotModel, q: F64, ctx: SampleContext) -> F64 | None:
        """``(N, n)`` offsets added to the commanded joint angles, or None."""
        return None

    def param_offsets(self, model: RobotModel, q: F64, ctx: SampleContext) -> F64 | None:
        """``(P,)`` or ``(N, P)`` offsets added to the chain parameters, or None."""
        return None

    def check_context(self, ctx: SampleContext) -> None:
        for name in self.requires:
            if getattr(ctx, name) is None:
                raise ValueError(f"effect {self.catalog_name!r} needs the sample context {name!r}")


# ------------------------------------------------------------------------- helpers for subclasses


def check_joints(effect: str, joints: tuple[int, ...], n_values: dict[str, tuple]) -> None:
    """Shared __post_init__ checks: 1-based unique joints, one finite value per joint per field."""
    if any((not isinstance(j, int | np.integer)) or j < 1 for j in joints):
        raise ValueError(f"{effect}: joints are 1-based integers, got {joints}")
    if len(set(joints)) != len(joints):
        raise ValueError(f"{effect}: joints must be unique, got {joints}")
    for name, vals in n_values.items():
        if len(vals) != len(joints):
            raise ValueError(f"{effect}: {name} needs one value per joint ({len(joints)}), got {len(vals)}")
        if not all(np.isfinite(v) for v in vals):
            raise ValueError(f"{effect}: {name} contains NaN or infinity")


def check_joints_exist(effect: str, joints: tuple[int, ...], model: RobotModel) -> None:
    bad = [j for j in joints if j > model.dof]
    if bad:
        raise ValueError(f"{effect}: joint(s) {bad} do not exist on {model.name} ({model.dof} joints)")


def joint_matrix(model: RobotModel, joints: tuple[int, ...], per_joint: F64) -> F64:
    """Scatter ``(N, len(joints))`` values into an ``(N, n)`` joint-offset array."""
    out = np.zeros((per_joint.shape[0], model.dof))
    out[:, [j - 1 for j in joints]] = per_joint
    return out
