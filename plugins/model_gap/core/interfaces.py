"""The contracts between the model-gap workflow core and the models and effects it works on.

The core (:mod:`plugins.model_gap.core.workflow`) knows nothing of robots: it sees a *problem* (a model with
its baseline calibration, fitted to measured data) and *candidate effects* (coming from plugins
through the ``vgr_model_effects`` hook). Everything it needs is linear algebra on whitened
residuals:

* :meth:`GapProblem.linearise` gives the residuals ``w = (measured - predicted) / sigma`` of the
  current model, shape ``(N, m)`` (N samples, m measured components, e.g. x y z), and the Jacobian
  ``A = d predicted / d theta / sigma`` of the parameters the model already fits (baseline
  calibration plus the effects added so far), shape ``(N, m, p)``;
* a :class:`Candidate` gives, for the current model, the whitened Jacobian ``B`` of the predictions
  with respect to its *linear* parameters (``(N, m, k)``); effects with a nonlinear *shape*
  parameter (a time constant) give one design per value of a grid;
* :meth:`GapProblem.add_effect` adds the chosen candidate to the model and refits everything
  (nonlinear least squares), returning the effect's parameters with their standard deviations;
  :meth:`GapProblem.fitted_effects` gives every added effect at the current (final) joint refit;
  :meth:`GapProblem.remove_effect` takes one out again and refits (the loop's backward check).
  A *tie term* (candidates the data cannot tell apart, added as one term) is added as one of them,
  the representative, with ``tied_with`` naming the others: the problem keeps that annotation (the
  model file writes it) and :class:`FittedEffect` carries it.

Effect plugins return :class:`EffectFamily` objects from ``vgr_model_effects``; a family turns a
problem into its candidates (one per place the effect can act: ``joint2``, ``camera`` ...), or
into a candidate marked ``unavailable`` with the reason (``needs dir1..dirN columns``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


class GapInputError(ValueError):
    """The data or the request cannot be analysed (too few samples, nothing to test ...)."""


@dataclass
class Linearisation:
    """The current model around its fitted parameters (whitened; see the module docstring)."""

    residual: F64  # (N, m) whitened residuals, measured - predicted
    jacobian: F64  # (N, m, p) whitened derivative of the predictions w.r.t. the fitted parameters
    names: list[str]  # the p fitted parameters
    sigma: F64  # (N,) noise sigma of each sample per component, in the residual's SI unit

    @property
    def n_samples(self) -> int:
        return self.residual.shape[0]

    @property
    def n_components(self) -> int:
        return self.residual.shape[1]

    def physical_residual(self) -> F64:
        """Residuals in SI units, ``(N, m)``."""
        return self.residual * self.sigma[:, None]


@dataclass
class Design:
    """Whitened derivative ``(N, m, k)`` of the predictions w.r.t. a candidate's linear parameters."""

    columns: F64
    shape: dict[str, float] = field(default_factory=dict)  # values of the nonlinear shape parameters


@dataclass
class Signature:
    """How to plot the residual against an effect's regressor.

    For sample *i* the plotted value is the scalar ``y_i = g_i . r_i / |g_i|^2`` (the value of the
    effect's own quantity, e.g. a joint deflection in rad, that would explain that sample's residual
    ``r_i`` alone), against the regressor ``x_i`` (gravity torque, approach direction, time ...).
    ``basis`` holds ``g_i``: the residual (SI) produced per unit of ``y``.
    """

    x: F64  # (N,)
    x_label: str
    basis: F64  # (N, m)
    y_label: str
    y_unit: str


@dataclass
class Feature:
    """A per-sample quantity along which the gap may concentrate (joint angle, torque, time ...)."""

    name: str
    label: str
    unit: str
    values: F64  # (N,)
    categorical: bool = False
    spatial: bool = False  # a coordinate of where the measurement was taken (the structure test's smooth field)


@runtime_checkable
class Candidate(Protocol):
    """One effect at one place, as the selection sees it."""

    name: str  # catalog name: joint_compliance
    where: str  # joint2, camera, robot, base, tool ...
    param_names: tuple[str, ...]  # linear parameters first, then shape parameters
    units: tuple[str, ...]
    shape_names: tuple[str, ...]  # nonlinear parameters (profiled over a grid), () for most effects
    unavailable: str | None  # why it cannot be tested on these data, or None
    lower: F64  # bounds of the linear parameters (physically meaningful range)
    upper: F64

    def designs(self, problem: GapProblem) -> list[Design]: ...

    def signature(self, problem: GapProblem) -> Signature | None: ...


@runtime_checkable
class EffectFamily(Protocol):
    """What a plugin returns from ``vgr_model_effects``: an effect type and where it can act."""

    name: str
    description: str
    requires: tuple[str, ...]  # data it needs (documentation and the report's 'not testable' list)

    def candidates(self, problem: GapProblem) -> list[Candidate]: ...


TIE_SEP = "|"


def tie_label(labels: list[str] | tuple[str, ...]) -> str:
    """The label of a tie term: its members' ``name@where`` labels, sorted, joined by ``|``."""
    return TIE_SEP.join(sorted(labels))


@dataclass
class FittedEffect:
    """An effect added to the model, with its refitted parameters (SI) and one-sigma uncertainties.

    A *tie term* (``tied_with`` not empty) is the representative effect of a group of candidates the
    data cannot tell apart: ``name`` / ``where`` / ``params`` / ``config`` are the representative's
    (what the model evaluates), but the term is not named as that effect: :attr:`label`,
    :attr:`tie_name` and :attr:`tie_where` name the whole group.

    ``params`` are in the effect's physical convention (a backlash is a play >= 0); ``values`` is the
    vector the model fits (``candidate.param_names`` order), which can differ in sign when the data
    count a direction the other way round: ``note`` then says so.
    """

    name: str
    where: str
    params: dict[str, float]
    param_std: dict[str, float]
    units: dict[str, str]
    config: dict[str, Any] = field(default_factory=dict)  # how to rebuild it (model-file form)
    tied_with: tuple[str, ...] = ()  # tie term: the other members' labels (name@where)
    values: tuple[float, ...] = ()  # the fitted vector (candidate.param_names order); () = params' values
    note: str = ""  # e.g. the data count a direction the other way round (a sign convention)

    def vector(self, names: tuple[str, ...] | list[str]) -> NDArray[np.float64]:
        """The fitted vector for the candidate's ``names`` (``values``, else ``params`` in that order)."""
        if self.values:
            return np.asarray(self.values[: len(names)], dtype=float)
        return np.array([self.params[n] for n in names], dtype=float)

    @property
    def tied(self) -> bool:
        return bool(self.tied_with)

    @property
    def representative(self) -> str:
        """``name@where`` of the effect the model evaluates (for a tie term: one of the group)."""
        return f"{self.name}@{self.where}"

    @property
    def members(self) -> list[str]:
        """The labels the term stands for, sorted (one for a named effect)."""
        return sorted({self.representative, *self.tied_with})

    @property
    def label(self) -> str:
        """``name@where`` of a named effect; ``a@x|b@y`` of a tie term (never one member's name alone)."""
        return tie_label(self.members) if self.tied else self.representative

    @property
    def tie_name(self) -> str:
        """``name`` as reported: a tie term's member names joined by ``|`` (in the order of :attr:`members`)."""
        return TIE_SEP.join(m.split("@", 1)[0] for m in self.members) if self.tied else self.name

    @property
    def tie_where(self) -> str:
        return TIE_SEP.join(m.split("@", 1)[1] for m in self.members) if self.tied else self.where

    @property
    def file_stem(self) -> str:
        """A file-name-safe form of :attr:`label` (``backlash_joint3``, ``tie_a_x_or_b_y``)."""
        if not self.tied:
            return f"{self.name}_{self.where}"
        return "tie_" + "_or_".join(m.replace("@", "_") for m in self.members)


@runtime_checkable
class GapProblem(Protocol):
    """A model fitted to data, which the workflow compares, augments and refits."""

    kind: str
    axis_names: tuple[str, ...]
    n_samples: int

    def linearise(self) -> Linearisation: ...

    def features(self) -> list[Feature]: ...

    def add_effect(self, candidate: Candidate, values: F64, *, tied_with: tuple[str, ...] = ()) -> FittedEffect: ...

    def fitted_effects(self) -> list[FittedEffect]: ...

    def remove_effect(self, candidate: Candidate) -> None: ...

    def describe(self) -> dict[str, Any]: ...

    def save_model(self, path: Path) -> Path: ...
