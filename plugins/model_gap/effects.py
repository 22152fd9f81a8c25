"""The model-gap catalog: effect families (registered through ``vgr_model_effects``) and their candidates.

A family is one catalog effect; on a problem it yields one candidate per place the effect can act.
Robot-side candidates wrap the fittable effects of :mod:`plugins.robot.effects` (their
Jacobians come from :meth:`RobotWithEffects.effect_jacobian`); measurement-side ones those of
:mod:`plugins.robot.effects.measurement`.

| family | where | parameters (SI) | needs |
| --- | --- | --- | --- |
| ``joint_offset`` | ``jointN`` | zero offset (rad) | |
| ``link_length`` | ``jointN`` | length error of the joint's longer DH length, a or d (m) | dh/mdh model |
| ``joint_compliance`` | ``jointN`` | deflection per N m of gravity torque (rad/(N m)) | link masses |
| ``backlash`` | ``jointN`` | total play (rad; fitted signed, reported >= 0: ``BacklashCandidate``) | ``dir1..dirN`` |
| ``encoder_eccentricity`` | ``jointN`` | sin and cos amplitudes (rad) | |
| ``thermal_drift`` | ``robot`` | strain of every link length at equilibrium (1), time constant (s) | ``t_s`` |
| ``thermal_drift`` | ``base`` | base height growth at equilibrium (m), time constant (s) | ``t_s`` |
| ``thermal_drift`` | ``jointN`` | the link length's growth (m), time constant (s); or m/K | ``t_s`` / ``temp_c`` |
| ``robot_scale`` | ``robot`` | strain of every robot length and the tool point, constant (1) | |
| ``base_frame`` | ``base`` | base pose error tx ty tz (m) rx ry rz (rad) | |
| ``tool_offset`` | ``tool`` | tool point error tx ty tz (m, flange frame) | |
| ``time_latency`` | sensor | latency of the measurement stream (s) | ``qdN_deg_s`` |
| ``depth_scale`` | sensor | relative range error (1) | ``range_mm`` |
| ``depth_bias`` | sensor | range offset (m) | ``range_mm`` |

``robot_scale`` is the arm at another steady temperature (``alpha dT``) or a scale error of its
nominal geometry: every length of the chain after the base (DH ``a`` / ``d``, POE link offsets, the
flange and the tool point) times ``1 + s``. The position of an all-revolute chain is homogeneous of
degree 1 in its lengths, so once the measurement frame is fitted it is *exactly* a range scale
``depth_scale`` of the sensor (``(1+e)(R x + t) = R((1+e) x) + (1+e) t``): the two tie, and the
workflow names neither: it adds them as one tie term (named after both) and reports them as
confounded with the advice that separates them (:data:`SCALE_TIE_ADVICE`).

Candidates the baseline calibration already explains (a joint offset of joint 1 when the measurement
frame is fitted, the base frame itself ...) are scored as *absorbed* by the workflow, not hidden.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.candidates import BacklashCandidate, MeasurementCandidate, RobotCandidate
from plugins.model_gap.problem import KinematicGapProblem
from plugins.robot import effects as fx
from plugins.robot.effects import RobotEffect
from plugins.robot.kinematics import RobotModel

F64 = NDArray[np.float64]

#: why a range scale and a uniform robot scale tie once the measurement frame is fitted, and what
#: separates them (given when the two explain the same part of the gap)
SCALE_TIE_ADVICE = (
    "with the measurement frame fitted a range scale of the sensor and a uniform scale of the robot (every "
    "length and the tool point: the arm at another steady temperature, or a scale error of its nominal "
    "geometry) give exactly the same data, and more poses do not help: measure a reference length with the "
    "same sensor (a calibrated scale bar) to fix the sensor's scale, or fix the measurement frame from an "
    "independent measurement (a registered sensor frame: --calibrate tool or none)"
)


# --------------------------------------------------------------------------- families


def _missing(problem: KinematicGapProblem, needs: tuple[str, ...]) -> str | None:
    have = problem.data.columns
    names = {
        "direction": "dir1..dirN",
        "t_s": "t_s",
        "qd": "qd1_deg_s..qdN_deg_s",
        "range": "range_mm",
        "payload_kg": "payload_kg",
    }
    miss = [names.get(n, n) for n in needs if n not in have]
    return f"needs the data column(s) {', '.join(miss)}" if miss else None


class _Family:
    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    requires: ClassVar[tuple[str, ...]] = ()

    def candidates(self, problem: Any) -> list:
        if getattr(problem, "kind", None) != "kinematic":
            return []
        missing = _missing(problem, self.requires)
        if missing:
            return [self._unavailable(problem, missing)]
        return self._candidates(problem)

    def _unavailable(self, problem: KinematicGapProblem, reason: str):
        return RobotCandidate(self.name, "*", fx.JointOffset(), (), (), np.zeros((0, 0)), np.zeros(0), np.zeros(0),
                              unavailable=reason)  # fmt: skip

    def _candidates(self, problem: KinematicGapProblem) -> list:
        raise NotImplementedError


def _per_joint(
    name, problem, make, params, units, regressor, lower=None, jac_floor=None, geometric=False
) -> list[RobotCandidate]:
    out = []
    k = len(params)
    for j in range(1, problem.model.dof + 1):
        out.append(
            RobotCandidate(
                name,
                f"joint{j}",
                make(j),
                tuple(p.format(j=j) for p in params),
                units,
                np.eye(k),
                np.full(k, -np.inf) if lower is None else np.full(k, lower),
                np.full(k, np.inf),
                regressor=regressor.format(j=j),
                joint=j,
                jac_floor=jac_floor,
                geometric=geometric,
            )
        )
    return out


class JointOffsetFamily(_Family):
    name = "joint_offset"
    description = "zero offset of a joint (its encoder reads a constant off)"

    def _candidates(self, problem):
        return _per_joint(
            self.name,
            problem,
            lambda j: fx.JointOffset((j,), (0.0,)),
            ("offset_joint{j}",),
            ("rad",),
            "q{j}",
            geometric=True,
        )


class LinkLengthFamily(_Family):
    name = "link_length"
    description = "length error of a link (the joint's longer DH length, a or d)"

    def _candidates(self, problem):
        if problem.model.convention not in ("dh", "mdh"):
            return [
                self._unavailable(problem, f"needs a dh/mdh model, {problem.model.name} is {problem.model.convention}")
            ]
        values = dict(zip(problem.model.param_names, problem.model.param_values, strict=True))
        out = _per_joint(
            self.name,
            problem,
            lambda j: fx.LinkLength((j,), (0.0,)),
            ("length_joint{j}",),
            ("m",),
            "q{j}",
            geometric=True,
        )
        for c in out:
            c.joint = None  # a length, not a joint angle: the signature uses the effect's own column
        return [c for c in out if max(abs(values[f"{c.where}.a"]), abs(values[f"{c.where}.d"])) >= 1e-6]


class JointComplianceFamily(_Family):
    name = "joint_compliance"
    description = "joint deflection proportional to the gravity torque (payload included)"

    def _candidates(self, problem):
        if problem.model.links is None:
            return [self._unavailable(problem, f"needs link masses in the model ({problem.model.name} has none)")]
        tau = problem.gravity_torque()
        out = _per_joint(
            self.name,
            problem,
            lambda j: fx.JointCompliance((j,), (0.0,)),
            ("compliance_joint{j}",),
            ("rad/(N m)",),
            "tau{j}",
        )
        return [c for c in out if np.ptp(tau[:, c.joint - 1]) > 1e-6 or np.abs(tau[:, c.joint - 1]).max() > 1e-6]


class BacklashFamily(_Family):
    name = "backlash"
    description = "gear play: the joint lags half the backlash behind its approach direction"
    requires = ("direction",)

    def _candidates(self, problem):
        out = _per_joint(
            self.name, problem, lambda j: fx.Backlash((j,), (0.0,)), ("backlash_joint{j}",), ("rad",), "dir{j}"
        )
        return [BacklashCandidate(**{f.name: getattr(c, f.name) for f in fields(c)}) for c in out]


class EncoderEccentricityFamily(_Family):
    name = "encoder_eccentricity"
    description = "once-per-revolution joint error a sin(q) + b cos(q)"

    def _candidates(self, problem):
        return _per_joint(
            self.name,
            problem,
            lambda j: fx.EncoderEccentricity((j,), (0.0,), (0.0,)),
            ("ecc_sin_joint{j}", "ecc_cos_joint{j}"),
            ("rad", "rad"),
            "q{j}",
        )


def _link_lengths(model: RobotModel) -> list[tuple[int, str, float]]:
    """``(joint, chain parameter, nominal value)`` of each joint's longer DH length (a or d), as
    ``link_length`` picks it; joint 1's ``d`` is left out: along the base axis it is the base height,
    whose growth is ``thermal_drift@base``."""
    if model.convention not in ("dh", "mdh"):
        return []
    values = dict(zip(model.param_names, model.param_values, strict=True))
    out = []
    for j in range(1, model.dof + 1):
        a, d = values[f"joint{j}.a"], values[f"joint{j}.d"]
        name, v = (f"joint{j}.a", a) if abs(a) >= abs(d) else (f"joint{j}.d", d)
        if abs(v) >= 1e-6 and not (j == 1 and name.endswith(".d")):
            out.append((j, name, float(v)))
    return out


class ThermalDriftFamily(_Family):
    name = "thermal_drift"
    description = (
        "warm-up growth of the link lengths (robot), of the base height (base) or of one link (jointN: with "
        "the warm-up time constant, or linearly with temp_c when the data log it)"
    )
    requires = ("t_s",)
    n_grid: ClassVar[int] = 12

    def candidates(self, problem: Any) -> list:
        if getattr(problem, "kind", None) != "kinematic":
            return []
        cols = problem.data.columns
        if "t_s" not in cols and "temp_c" not in cols:
            return [self._unavailable(problem, "needs the data column(s) t_s (or temp_c for one link)")]
        if "t_s" not in cols:  # one link growing with the logged temperature still testable
            return self._links(problem, None)
        return self._candidates(problem)

    def _links(self, problem, bounds: dict | None) -> list:
        """``thermal_drift@jointN``: the joint's link length grows, linearly with ``temp_c`` when the data
        have it, else with the warm-up time constant (``bounds``: its grid and range)."""
        out = []
        by_temp = "temp_c" in problem.data.columns
        if by_temp and np.ptp(problem.data.samples.temp_c) <= 0:
            return [self._unavailable(problem, "temp_c does not vary")]
        for j, name, _ in _link_lengths(problem.nominal):
            if by_temp:
                ref = float(np.mean(problem.data.samples.temp_c))
                proto: RobotEffect = fx.TemperatureExpansion((name,), (0.0,), ref)
                cand = RobotCandidate(
                    self.name, f"joint{j}", proto, (f"growth_joint{j}_per_k",), ("m/K",), np.eye(1),
                    np.array([-np.inf]), np.array([np.inf]), regressor="temp_c",
                )  # fmt: skip
            elif bounds is not None:
                cand = RobotCandidate(
                    self.name, f"joint{j}", fx.ThermalDrift((name,), (0.0,), 1800.0),
                    (f"growth_joint{j}", "time_constant"), ("m", "s"), np.eye(2), np.array([-np.inf]),
                    np.array([np.inf]), ("time_constant",), regressor="t_s", **bounds,
                )  # fmt: skip
            else:
                continue
            out.append(cand)
        return out

    def _candidates(self, problem):
        t = problem.data.samples.t_s
        span = float(np.ptp(t))
        if span <= 0:
            return [self._unavailable(problem, "t_s does not vary")]
        # A time constant shorter than the first samples' spacing is a constant, not a drift (and a
        # constant length change is link_length / depth_scale): the grid starts where 10 % of the
        # samples have been taken.
        tau_min = max(1.0, span / 100.0, float(np.quantile(t - t.min(), 0.1)))
        grid = tuple(np.geomspace(tau_min, 2.0 * span, self.n_grid).tolist())
        bounds = dict(shape_grid=grid, shape_lower=(1.0,), shape_upper=(50.0 * span,))
        model = problem.model
        names, lengths = [], []
        for n, v in zip(model.param_names, problem.nominal.param_values, strict=True):
            if n.startswith("joint") and n.rsplit(".", 1)[-1] in ("a", "d") and abs(v) > 1e-9:
                names.append(n)
                lengths.append(float(v))
        k = len(names)
        robot_map = np.zeros((k + 1, 2))
        robot_map[:k, 0] = lengths
        robot_map[k, 1] = 1.0
        out = []
        if k:
            out.append(
                RobotCandidate(
                    self.name, "robot", fx.ThermalDrift(tuple(names), (0.0,) * k, 1800.0), ("strain", "time_constant"),
                    ("1", "s"), robot_map, np.array([-np.inf]), np.array([np.inf]), ("time_constant",), regressor="t_s",
                    **bounds,
                )
            )  # fmt: skip
        out.append(
            RobotCandidate(
                self.name, "base", fx.ThermalDrift(("base.tz",), (0.0,), 1800.0), ("drift_base_tz", "time_constant"),
                ("m", "s"), np.eye(2), np.array([-np.inf]), np.array([np.inf]), ("time_constant",), regressor="t_s",
                **bounds,
            )
        )  # fmt: skip
        return out + self._links(problem, bounds)


def uniform_scale_offsets(model: RobotModel) -> dict[str, float]:
    """Chain-parameter offsets per unit uniform scale of the robot: ``{name: d value / d s}``.

    Every translation of the chain after the base (the base is where the robot stands, not part of
    it) times ``1 + s``: a translation parameter (DH ``a`` / ``d``, ``tool.tx`` ...) by its value; a
    fixed transform's translation ``F_t`` through the translation parameters next to it (a POE link
    offset, the flange, the nominal tool): ``F Trans(t) = Trans(F_t + F_R t)`` takes ``F_R^T F_t`` on
    the three parameters right after ``F``, ``Trans(t) F = Trans(t + F_t) F_R`` takes ``F_t`` on those
    right before it. Raises ValueError when a fixed translation has no such neighbours.
    """
    chain = model.chain
    ops = chain.ops
    values = chain.values
    out = np.zeros(len(chain.param_names))

    def triple(start: int) -> list[int] | None:
        seg = ops[start : start + 3]
        if start < 0 or len(seg) < 3 or sorted(o.kind for o in seg) != ["tx", "ty", "tz"]:
            return None
        if any(o.group == "base" for o in seg):
            return None
        return [start + ("tx", "ty", "tz").index(o.kind) for o in seg]

    for i, op in enumerate(ops):
        if op.group == "base":
            continue
        if op.kind in ("tx", "ty", "tz"):
            k = chain.index(op.name)
            out[k] += values[k]
        elif op.kind == "fixed":
            assert op.matrix is not None
            F_R, F_t = op.matrix[:3, :3], op.matrix[:3, 3]
            if not np.any(np.abs(F_t) > 1e-12):
                continue
            after, before = triple(i + 1), triple(i - 3)
            if after is not None:
                d, idx = F_R.T @ F_t, after
            elif before is not None:
                d, idx = F_t, before
            else:
                raise ValueError(
                    f"{model.name}: the fixed translation of group {op.group!r} has no translation parameters next "
                    "to it, so a uniform scale of the robot cannot be expressed"
                )
            for axis, j in enumerate(idx):
                out[chain.index(ops[j].name)] += d[axis]
    return {n: float(v) for n, v in zip(chain.param_names, out, strict=True) if abs(v) > 1e-12}


class RobotScaleFamily(_Family):
    name = "robot_scale"
    description = (
        "uniform scale of the robot: every length and the tool point times (1 + s) (the arm at another steady "
        "temperature, or a scale error of its nominal geometry)"
    )

    def _candidates(self, problem):
        try:
            offsets = uniform_scale_offsets(problem.model)
        except ValueError as e:
            return [self._unavailable(problem, str(e))]
        names = tuple(offsets)
        return [
            RobotCandidate(
                self.name, "robot", fx.GeometricErrors(names, (0.0,) * len(names)), ("scale",), ("1",),
                np.array([[offsets[n]] for n in names]), np.array([-np.inf]), np.array([np.inf]), regressor="reach",
                tie_advice={"depth_scale": SCALE_TIE_ADVICE}, geometric=True,
            )
        ]  # fmt: skip


class BaseFrameFamily(_Family):
    name = "base_frame"
    description = "the robot base is not where the model puts it (6-DOF pose error)"

    def _candidates(self, problem):
        names = tuple(f"base.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
        return [
            RobotCandidate(
                self.name, "base", fx.BaseFrameError(), names, ("m", "m", "m", "rad", "rad", "rad"), np.eye(6),
                np.full(6, -np.inf), np.full(6, np.inf), regressor="reach", geometric=True,
            )
        ]  # fmt: skip


class ToolOffsetFamily(_Family):
    name = "tool_offset"
    description = "the measured tool point is not where the model puts it (flange frame)"

    def _candidates(self, problem):
        comps = ("tx", "ty", "tz")
        return [
            RobotCandidate(
                self.name, "tool", fx.ToolOffsetError(comps, (0.0,) * 3), tuple(f"tool.{c}" for c in comps), ("m",) * 3,
                np.eye(3), np.full(3, -np.inf), np.full(3, np.inf), regressor="reach", geometric=True,
            )
        ]  # fmt: skip


class _MeasurementFamily(_Family):
    def _unavailable(self, problem, reason):
        return MeasurementCandidate(self.name, problem.data.sensor, unavailable=reason)

    def _candidates(self, problem):
        return [MeasurementCandidate(self.name, problem.data.sensor)]


class TimeLatencyFamily(_MeasurementFamily):
    name = "time_latency"
    description = "the measurement stream lags the joint stream (moving robot)"
    requires = ("qd",)

    def _candidates(self, problem):
        if not np.any(np.abs(problem.data.qd) > 1e-9):
            return [self._unavailable(problem, "the robot never moves at a measurement (all qd = 0)")]
        return super()._candidates(problem)


class DepthScaleFamily(_MeasurementFamily):
    name = "depth_scale"
    description = "the ranging sensor's distances are scaled"
    requires = ("range",)

    def _candidates(self, problem):
        return [MeasurementCandidate(self.name, problem.data.sensor, tie_advice={"robot_scale": SCALE_TIE_ADVICE})]


class DepthBiasFamily(_MeasurementFamily):
    name = "depth_bias"
    description = "the ranging sensor's distances are offset"
    requires = ("range",)


FAMILIES: tuple[type[_Family], ...] = (
    JointOffsetFamily,
    LinkLengthFamily,
    JointComplianceFamily,
    BacklashFamily,
    EncoderEccentricityFamily,
    ThermalDriftFamily,
    RobotScaleFamily,
    BaseFrameFamily,
    ToolOffsetFamily,
    TimeLatencyFamily,
    DepthScaleFamily,
    DepthBiasFamily,
)


def builtin_families() -> list[_Family]:
    """One instance of every built-in family (what ``vgr_model_effects`` returns)."""
    return [cls() for cls in FAMILIES]
