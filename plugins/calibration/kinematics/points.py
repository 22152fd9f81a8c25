"""Several measured points per pose: one tool point per name, one measurement frame and geometry for all.

A laser tracker measuring several reflectors on the tool (or a camera several markers) gives one row
per point and pose; the data's ``point`` column names the point. The points share the robot's
geometry and the measurement frame; each has its own position on the flange. The model's own tool
(the chain's ``tool.tx ty tz``) is the *first* point's (in order of appearance); every other point
``k`` has three parameters ``tool[k].tx ty tz``, its offset from the first in the chain's tool
parameters (for a tool without a rotated fixed part: in the flange frame). A point's parameters are
linear: their Jacobian column is the tool translation's column on that point's rows, zero elsewhere.

The offsets enter the model as a per-sample parameter offset (:meth:`ToolPoints.effect`, a
:class:`~plugins.robot.effects.RobotEffect`), so every Jacobian -- the chain's, an effect's -- is taken
at the point each row measures.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.kinematics.data import KinematicSamples
from plugins.robot.effects import ParamSpec, RobotEffect, SampleContext
from plugins.robot.kinematics import RobotModel

F64 = NDArray[np.float64]
AXES = ("tx", "ty", "tz")
TOOL = tuple(f"tool.{a}" for a in AXES)
POINT_PARAM = re.compile(r"^tool\[(.+)\]\.(tx|ty|tz)$")


class PointOffsets(RobotEffect):
    """The tool translation of each sample's measured point: ``(N, 3)`` added to ``tool.tx ty tz``."""

    catalog_name = "tool_points"

    def __init__(self, per_sample: F64) -> None:
        self.per_sample = np.asarray(per_sample, dtype=float)

    def param_specs(self) -> tuple[ParamSpec, ...]:
        return ()

    def param_offsets(self, model: RobotModel, q: F64, ctx: SampleContext) -> F64 | None:
        if q.shape[0] != self.per_sample.shape[0]:
            raise ValueError(f"{q.shape[0]} samples, but the measured points are given for {self.per_sample.shape[0]}")
        out = np.zeros((q.shape[0], len(model.param_names)))
        out[:, [model.chain.index(n) for n in TOOL]] = self.per_sample
        return out


@dataclass(frozen=True)
class ToolPoints:
    """The measured points' names (the first is the model's own tool point) and offsets ``(K, 3)``."""

    names: tuple[str, ...]
    offsets: F64  # row 0 is zero: the first point is the chain's tool

    @classmethod
    def of(cls, samples: KinematicSamples, known: dict[str, F64] | None = None) -> ToolPoints | None:
        """The points of ``samples`` (None: one point or no ``point`` column). ``known`` offsets (by name,
        from a stored model) are kept; the first known point stays the first."""
        names = samples.point_names
        if known:
            unknown = [n for n in names if n not in known]
            if unknown:
                raise ValueError(
                    f"the data measure point(s) {unknown} the model does not know (it has {sorted(known)})"
                )
            order = tuple(known)
            return cls(order, np.array([np.asarray(known[n], dtype=float) for n in order]))
        if len(names) < 2:
            return None
        return cls(names, np.zeros((len(names), 3)))

    def param_names(self) -> list[str]:
        """``tool[k].tx ty tz`` of every point but the first."""
        return [f"tool[{k}].{a}" for k in self.names[1:] for a in AXES]

    def index(self, samples: KinematicSamples) -> NDArray[np.int64]:
        """``(N,)``: the point each sample measures (its position in :attr:`names`)."""
        if samples.point is None:
            raise ValueError(f"the model has measured points {list(self.names)}: the data need a point column")
        pos = {n: i for i, n in enumerate(self.names)}
        missing = sorted(set(samples.point.tolist()) - set(pos))
        if missing:
            raise ValueError(f"the data measure point(s) {missing} the model does not know (it has {list(self.names)})")
        return np.array([pos[n] for n in samples.point.tolist()], dtype=np.int64)

    def effect(self, samples: KinematicSamples) -> PointOffsets:
        """The per-sample offset of each row's point (see the module docstring)."""
        return PointOffsets(self.offsets[self.index(samples)])

    def values(self, model: RobotModel, values: F64 | None, samples: KinematicSamples) -> F64:
        """``(N, P)`` chain values with each row's point offset added to the tool translation."""
        v = model.param_values if values is None else np.asarray(values, dtype=float)
        return v + self.effect(samples).param_offsets(model, samples.q, SampleContext())  # type: ignore[operator]

    def columns(self, J_params: F64, model: RobotModel, samples: KinematicSamples) -> F64:
        """``(N, r, 3 (K - 1))``: the point parameters' columns from the chain-parameter Jacobian."""
        idx = [model.chain.index(n) for n in TOOL]
        k_of = self.index(samples)
        cols = [J_params[:, :, idx] * (k_of == k)[:, None, None] for k in range(1, len(self.names))]
        return np.concatenate(cols, axis=2) if cols else np.zeros((J_params.shape[0], J_params.shape[1], 0))

    def with_offsets(self, flat: F64) -> ToolPoints:
        """New offsets of the points after the first, flattened as :meth:`param_names`."""
        off = np.zeros_like(self.offsets)
        off[1:] = np.asarray(flat, dtype=float).reshape(-1, 3)
        return replace(self, offsets=off)

    def flat(self) -> F64:
        return self.offsets[1:].reshape(-1).copy()

    def flange_points(self, model: RobotModel) -> dict[str, list[float]]:
        """Each point's position in the flange frame (m): the model's TCP with that point's offset."""
        out = {}
        for name, off in zip(self.names, self.offsets, strict=True):
            v = model.param_values.copy()
            v[[model.chain.index(n) for n in TOOL]] += off
            out[name] = [float(x) for x in model.with_values(v).T_flange_tcp[:3, 3]]
        return out

    def as_dict(self) -> dict[str, list[float]]:
        """Offsets by name (what a model file stores to rebuild this: :meth:`of` with ``known``)."""
        return {n: [float(x) for x in off] for n, off in zip(self.names, self.offsets, strict=True)}


def split_names(names: list[str]) -> tuple[list[int], list[int]]:
    """Positions of the chain parameters and of the point parameters (``tool[k].t*``) in ``names``."""
    pts = [i for i, n in enumerate(names) if POINT_PARAM.match(n)]
    return [i for i in range(len(names)) if i not in pts], pts


def fit_point_offsets(model: RobotModel, samples: KinematicSamples, points: ToolPoints) -> ToolPoints:
    """Each point's offset by linear least squares given the model (its frame and first tool point)."""
    g = model.chain.evaluate(samples.q, record_groups=True).group_frames
    F = g.get("flange", g[f"joint{model.dof}"])
    k_of = points.index(samples)
    base_pt = np.asarray(model.T_flange_tcp[:3, 3])
    off = points.offsets.copy()
    for k in range(1, len(points.names)):
        rows = k_of == k
        A = F[rows, :3, :3].reshape(-1, 3)
        b = (samples.positions[rows] - F[rows, :3, 3] - F[rows, :3, :3] @ base_pt).reshape(-1)
        off[k], *_ = np.linalg.lstsq(A, b, rcond=None)
    return replace(points, offsets=off)


def first_point(samples: KinematicSamples, points: ToolPoints) -> KinematicSamples:
    """The samples of the first point only (what the single-tool initial fits use)."""
    return samples.subset(np.flatnonzero(points.index(samples) == 0))
