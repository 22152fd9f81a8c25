"""The robot-kinematics model-gap problem: a robot model, its baseline calibration, measured tool points.

Prediction of the measured point for sample *i* (commanded joints ``q``, context: time, approach
direction, payload; joint velocities ``qd``)::

    q_seen  = q - L qd                                    (time_latency, if added)
    T       = RobotWithEffects(model, robot effects).fk(q_seen, context)
    p       = T[:3, 3]                                    (measurement frame = the model's world)
    p_meas  = p (1 + e + b / |p|)                         (depth_scale e, depth_bias b, if added)

The model's ``T_world_base`` is the measurement frame ``T_meas_base``. The **baseline calibration**
(``calibrate``) decides what is fitted before any effect is tried, reusing the kinematic
calibration (:mod:`plugins.calibration.kinematics`):

* ``frame``: the measurement frame (``base.tx .. base.rz``), started from a rigid fit;
* ``tool``: the measured point on the flange (``tool.tx ty tz``), started from a linear fit;
* ``joints``: the identifiable DH / MDH / POE joint parameters (a full kinematic calibration);
* ``none`` (empty): the model's frames are trusted as they are.

The default (:data:`DEFAULT_CALIBRATION`) is all three: every real robot has geometric errors, and
an effect is only worth naming after the geometry the data identify has been calibrated. Parameters
that are not identifiable from the data are fixed (identifiability analysis of the kinematic
calibration) and the report says which (:attr:`KinematicGapProblem.calibration_notes`);
:func:`.analyse.build_problem` falls back to the frame and the tool when the data cannot carry the
joint geometry at all (too few samples, a joint calibration that fails). Every added effect is
refitted together with the baseline (scipy ``least_squares``, analytic chain Jacobians,
:meth:`RobotWithEffects.effect_jacobian` for the effects), so an effect never takes credit for what
the calibration explains.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from plugins.calibration.kinematics import (
    KinematicCalibrationConfig,
    ToolPoints,
    analyse,
    calibrate_kinematics,
    candidate_parameters,
    initial_frames,
)
from plugins.calibration.kinematics.points import first_point, fit_point_offsets, split_names
from plugins.model_gap.columns import CandidateColumns
from plugins.model_gap.core.interfaces import Candidate, Feature, FittedEffect, GapInputError, Linearisation
from plugins.model_gap.data import GapData
from plugins.model_gap.features import features
from plugins.robot.effects.measurement import apply_range_distortion, range_distortion_jacobian
from plugins.robot.kinematics import RobotModel
from plugins.robot.with_effects import RobotWithEffects

F64 = NDArray[np.float64]
CALIBRATION_LEVELS = ("frame", "tool", "joints")
DEFAULT_CALIBRATION = CALIBRATION_LEVELS  # the full calibration the data identify
MIN_SAMPLES = 6  # below this the rigid frame fit is degenerate; the workflow asks for more (plugins.model_gap.core)


@dataclass
class ProblemConfig:
    """How the baseline is calibrated and what the noise is."""

    calibrate: tuple[str, ...] = DEFAULT_CALIBRATION
    noise_m: float | None = None  # per-axis 1-sigma; None: the data's sigma column
    noise_source: str = "given"  # given | data column | estimated (see plugins.model_gap.core.noise)
    parameterisation: str | None = None  # for "joints": dh | mdh | poe (default: the model's)
    max_nfev: int = 100
    requested: str = "default"  # what the user asked for: "default" (the full calibration) or the levels
    # several measured points (a point column): each point's offset from the first, known from a stored
    # model (name -> tool-parameter offset, m); None: fitted with the tool (kinematic_calibration.points)
    tool_points: dict[str, list[float]] | None = None


class KinematicGapProblem(CandidateColumns):
    """See the module docstring. Implements :class:`plugins.model_gap.core.interfaces.GapProblem`."""

    kind = "kinematic"
    axis_names = ("x", "y", "z")
    report_unit = "mm"
    report_scale = 1e3

    def __init__(self, model: RobotModel, data: GapData, config: ProblemConfig | None = None) -> None:
        cfg = config or ProblemConfig()
        sigma = checked_noise(model, data, cfg)
        self.cfg = cfg
        self.data = data
        self.nominal = model
        self.sigma = sigma
        self.n_samples = data.n_samples
        self.ctx = data.samples.context()
        self.q = data.samples.q
        self.qd = data.qd
        self.accepted: list[tuple[Any, F64]] = []  # (candidate, values)
        self.tied_with: dict[str, tuple[str, ...]] = {}  # tie terms: representative label -> the other members
        self.calibration_notes: list[str] = []
        self.joint_calibration_failed: str | None = None  # why the joint calibration cannot be used
        try:
            self.points = ToolPoints.of(data.samples, cfg.tool_points)
        except ValueError as e:
            raise GapInputError(str(e)) from None
        if self.points is not None and cfg.tool_points is None and "tool" not in cfg.calibrate:
            raise GapInputError("several measured points (a point column) need the tool calibrated (--calibrate tool)")
        self._calibrate_baseline()

    # ----------------------------------------------------------------------------- baseline

    def _calibrate_baseline(self) -> None:
        cfg, samples = self.cfg, self.data.samples
        frame, tool = "frame" in cfg.calibrate, "tool" in cfg.calibrate
        kc = KinematicCalibrationConfig(
            parameterisation=cfg.parameterisation,  # type: ignore[arg-type]
            estimate_base=frame,
            estimate_tool=tool,
            noise_position_m=float(np.median(self.sigma)),
            holdout_fraction=0.0,
        )
        if "joints" in cfg.calibrate:
            cal = calibrate_kinematics(self.nominal, samples, config=kc)
            self.model = self._gravity_follows_base(cal.model)
            self.points = cal.points if self.points is not None and cal.points is not None else self.points
            names = list(cal.result.param_names)
            keep = ("not identifiable", "do not excite", "residuals for")
            self.calibration_notes += [r for r in cal.result.reasons if any(k in r for k in keep)]
            if cal.result.verdict == "failed":
                self.joint_calibration_failed = "; ".join(r for r in cal.result.reasons if r) or "failed"
        else:
            first = samples if self.points is None else first_point(samples, self.points)
            model = initial_frames(self.nominal, first, frame, tool) if (frame or tool) else self.nominal
            self.model = self._gravity_follows_base(model)
            names = [n for n in candidate_parameters(self.model, False, kc) if not n.startswith("joint")]
            if self.points is not None and tool:
                self.points = fit_point_offsets(self.model, samples, self.points)
                names += self.points.param_names()
        self.base_names: list[str] = []
        if names:
            J = self._predict(jacobian=True, base_names=names)[1] / self.sigma[:, None, None]
            ident = analyse(J.reshape(-1, len(names)), names)
            self.base_names = ident.kept
            if ident.dropped:
                self.calibration_notes.append(
                    "not identifiable from these data, kept at their current values: "
                    + "; ".join(ident.describe_dropped())
                )
        self.refit()

    def _gravity_follows_base(self, model: RobotModel) -> RobotModel:
        """``model`` with gravity expressed in its world frame (the measurement frame once fitted).

        The nominal model's gravity is given in the nominal world; moving the base to the measurement
        frame moves the world, so gravity (hence the gravity torque of ``joint_compliance``) turns along.
        """
        R = model.T_world_base[:3, :3] @ self.nominal.T_world_base[:3, :3].T
        g = R @ self.nominal.gravity_world
        if np.allclose(g, model.gravity_world, rtol=0, atol=1e-12):
            return model
        return RobotModel(
            model.name,
            model.convention,
            model.chain,
            model.joints,
            links=model.links,
            gravity_world=g,
            description=model.description,
            sources=model.sources,
            home=model.home,
        )

    def set_noise(self, noise_m: float, source: str) -> None:
        """State a new per-axis noise sigma (m) for every sample (an estimate, say) and refit.

        The fit itself does not depend on a uniform noise scale (the whitening cancels), so this only
        rescales the residuals, Jacobians and the chi-square the workflow sees.
        """
        if not (np.isfinite(noise_m) and noise_m > 0):
            raise GapInputError(f"the noise sigma must be a positive number, got {noise_m}")
        self.sigma = np.full(self.n_samples, float(noise_m))
        self.cfg = replace(self.cfg, noise_m=float(noise_m), noise_source=source)
        self.refit()

    # ----------------------------------------------------------------------------- prediction

    def _split(self, accepted):
        robot = [(c, v) for c, v in accepted if c.side == "robot"]
        meas = {c.name: float(v[0]) for c, v in accepted if c.side == "measurement"}
        return robot, meas

    def _robot(self, model: RobotModel, effects: list, points: ToolPoints | None) -> RobotWithEffects:
        """``model`` with ``effects``, every row evaluated at its measured point (several points: the
        points' offsets come first, as a per-sample effect, so every Jacobian is taken there)."""
        if points is None:
            return RobotWithEffects(model, effects)
        return RobotWithEffects(model, [points.effect(self.data.samples), *effects])

    def _predict(
        self,
        model: RobotModel | None = None,
        accepted: list[tuple[Any, F64]] | None = None,
        points: ToolPoints | None = None,
        *,
        jacobian: bool = False,
        base_names: list[str] | None = None,
    ) -> tuple[F64, F64 | None]:
        """Predicted measurements ``(N, 3)`` and (optionally) their Jacobian ``(N, 3, P)`` (SI, unwhitened).

        Jacobian columns: the ``base_names`` chain (or point) parameters, then every accepted effect's values.
        """
        model = self.model if model is None else model
        accepted = self.accepted if accepted is None else accepted
        points = self.points if points is None else points
        names = self.base_names if base_names is None else base_names
        robot, meas = self._split(accepted)
        lat = meas.get("time_latency", 0.0)
        q = self.q - lat * self.qd if (lat and self.qd is not None) else self.q
        rw = self._robot(model, [c.effect(v) for c, v in robot], points)
        qa, va = rw.actual_state(q, self.ctx)
        T = model.fk(qa, va)
        p = T[:, :3, 3]
        e, b = meas.get("depth_scale", 0.0), meas.get("depth_bias", 0.0)
        depth = any(c.name in ("depth_scale", "depth_bias") for c, _ in accepted)
        pm = apply_range_distortion(p, e, b) if depth else p
        if not jacobian:
            return pm, None
        cols = []
        if names:
            chain_pos, point_pos = split_names(list(names))
            _, Jp = model.chain.screw_jacobian(qa, va, columns="params")
            base = np.zeros((self.n_samples, 3, len(names)))
            base[:, :, chain_pos] = Jp[:, :3, [model.chain.index(names[i]) for i in chain_pos]]
            if point_pos and points is not None:
                base[:, :, point_pos] = points.columns(Jp[:, :3, :], model, self.data.samples)
            cols.append(base)
        if robot:  # differentiated at values inside the effects' domains (linear effects: same columns)
            rw_j = self._robot(model, [c.effect(c.jac_values(v)) for c, v in robot], points)
            k0 = 0 if points is None else 1
            for i, (c, v) in enumerate(robot):
                cols.append(rw_j.effect_jacobian(i + k0, q, self.ctx)[:, :3, :] @ c.jac_map(c.jac_values(v)))
        for c, _v in accepted:
            if c.side != "measurement":
                continue
            if c.name == "time_latency":
                _, Jq = model.chain.screw_jacobian(qa, va)
                cols.append(-np.einsum("nij,nj->ni", Jq[:, :3, :], self.qd)[:, :, None])
            elif c.name == "depth_scale":
                cols.append(np.zeros((self.n_samples, 3, 1)))  # filled after the distortion below
            else:
                cols.append(np.zeros((self.n_samples, 3, 1)))
        J = np.concatenate(cols, axis=2) if cols else np.zeros((self.n_samples, 3, 0))
        if depth:
            J = range_distortion_jacobian(p, e, b) @ J
            k = len(names) + sum(len(c.param_names) for c, _ in robot)
            for c, _v in accepted:
                if c.side != "measurement":
                    continue
                if c.name == "depth_scale":
                    J[:, :, k] = p
                elif c.name == "depth_bias":
                    J[:, :, k] = p / np.linalg.norm(p, axis=1, keepdims=True)
                k += 1
        return pm, J

    def _reorder_accepted_columns(self) -> list[str]:
        robot = [(c, v) for c, v in self.accepted if c.side == "robot"]
        meas = [(c, v) for c, v in self.accepted if c.side == "measurement"]
        self.accepted = robot + meas  # the Jacobian's column order
        return [f"{c.name}@{c.where}.{p}" for c, _ in self.accepted for p in c.param_names]

    # ----------------------------------------------------------------------------- fitting

    def _unpack_state(self, x: F64) -> tuple[RobotModel, list[tuple[Any, F64]], ToolPoints | None]:
        nb = len(self.base_names)
        chain_pos, point_pos = split_names(list(self.base_names))
        v = self.model.param_values.copy()
        if chain_pos:
            v[[self.model.chain.index(self.base_names[i]) for i in chain_pos]] += x[chain_pos]
        model = self._gravity_follows_base(self.model.with_values(v))
        points = self.points
        if point_pos and points is not None:
            points = points.with_offsets(points.flat() + x[point_pos])
        accepted, k = [], nb
        for c, val in self.accepted:
            accepted.append((c, x[k : k + val.size].copy()))
            k += val.size
        return model, accepted, points

    def refit(self, *, effects: bool = True, loss: str = "linear", f_scale: float = 1.0) -> tuple[F64, float, int]:
        """Nonlinear least squares of the baseline parameters and every accepted effect together
        (``effects=False``: the baseline parameters alone, the effects held at their values). ``loss`` /
        ``f_scale``: scipy's robust loss and its scale in whitened units (the outlier screen's refit,
        :mod:`.robust_fit`); the default is plain least squares.

        Returns ``(covariance of the full state, a-posteriori variance factor, dof)``.
        """
        self._reorder_accepted_columns()
        nb = len(self.base_names)
        held = np.concatenate([np.zeros(0)] + [v for _, v in self.accepted])
        x0 = np.concatenate([np.zeros(nb), held])
        lo = np.concatenate([np.full(nb, -np.inf)] + [c.bounds()[0] for c, _ in self.accepted])
        hi = np.concatenate([np.full(nb, np.inf)] + [c.bounds()[1] for c, _ in self.accepted])
        if not effects:  # the effects are part of the model being checked: only the baseline moves
            x0, lo, hi = x0[:nb], lo[:nb], hi[:nb]
        x0 = np.clip(x0, lo, hi)
        meas = self.data.samples.positions
        s = self.sigma[:, None]

        def state(x: F64) -> tuple[RobotModel, list[tuple[Any, F64]], ToolPoints | None]:
            return self._unpack_state(x if effects else np.concatenate([x, held]))

        def fun(x: F64) -> F64:
            return ((meas - self._predict(*state(x))[0]) / s).ravel()

        def jac(x: F64) -> F64:
            J = self._predict(*state(x), jacobian=True)[1]
            return -(J / s[:, :, None]).reshape(meas.size, -1)[:, : x.size]

        if x0.size:
            sol = least_squares(
                fun,
                x0,
                jac=jac,
                bounds=(lo, hi),
                x_scale="jac",
                method="trf",
                max_nfev=self.cfg.max_nfev,
                loss=loss,
                f_scale=f_scale,
            )
            x = sol.x
        else:
            x = x0
        self.model, self.accepted, self.points = state(x)
        return self.covariance()

    def covariance(self) -> tuple[F64, float, int]:
        """``(covariance, a-posteriori variance factor s^2, dof)`` of the full state at the current values.

        ``s^2 (J^T J)^+`` with the whitened Jacobian (Gauss-Newton); no refit, so every report of the
        same state (``gap_report.json``, the model files) shows the same uncertainties.
        """
        meas = self.data.samples.positions
        s = self.sigma[:, None]
        pred, J = self._predict(jacobian=True)
        r = ((meas - pred) / s).ravel()
        Jw = (J / s[:, :, None]).reshape(r.size, -1)
        n = Jw.shape[1]
        dof = max(1, r.size - n)
        s2 = float(r @ r) / dof
        if not n:
            return np.zeros((0, 0)), s2, dof
        # columns scaled to unit norm first: the parameters' units differ by many orders of magnitude
        # (rad, m, a time constant in s), and a pseudo-inverse of the raw normal matrix would truncate
        # the small-scaled directions (reporting a near-zero sigma for a time constant, say)
        d = np.linalg.norm(Jw, axis=0)
        d = np.where(d > 0, d, 1.0)
        Js = Jw / d
        cov = s2 * np.linalg.pinv(Js.T @ Js, rcond=1e-12) / np.outer(d, d)
        return cov, s2, dof

    # ----------------------------------------------------------------------------- GapProblem API

    def linearise(self) -> Linearisation:
        names = list(self.base_names) + self._reorder_accepted_columns()
        pred, J = self._predict(jacobian=True)
        s = self.sigma[:, None]
        return Linearisation((self.data.samples.positions - pred) / s, J / s[:, :, None], names, self.sigma.copy())

    def add_effect(self, candidate: Candidate, values: F64, *, tied_with: tuple[str, ...] = ()) -> FittedEffect:
        """Add the candidate and refit everything; the effect's values and sigmas right after this refit.

        ``tied_with``: the candidate is the representative of a tie term (the labels of the other
        members): evaluated as itself, annotated as the group (:class:`FittedEffect`, the model file).
        """
        self.accepted.append((candidate, np.asarray(values, dtype=float).copy()))
        if tied_with:
            self.tied_with[f"{candidate.name}@{candidate.where}"] = tuple(tied_with)
        self.refit()
        return next(fe for (c, _), fe in zip(self.accepted, self.fitted_effects(), strict=True) if c is candidate)

    def remove_effect(self, candidate: Candidate) -> None:
        """Take an added effect out of the model again and refit the rest."""
        kept = [(c, v) for c, v in self.accepted if c is not candidate]
        if len(kept) == len(self.accepted):
            raise ValueError(f"{candidate.name}@{candidate.where} is not part of the model")
        self.accepted = kept
        self.tied_with.pop(f"{candidate.name}@{candidate.where}", None)
        self.refit()

    def fitted_effects(self) -> list[FittedEffect]:
        """Every accepted effect at the current (jointly refitted) state, with one-sigma uncertainties.

        The values and sigmas of an effect change when later effects are added (the joint refit moves
        it, the residual variance factor shrinks): the final report takes them from here, not from
        the round in which the effect was added.
        """
        cov, _, _ = self.covariance()
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        out, k = [], len(self.base_names)
        for c, v in self.accepted:
            std = sd[k : k + v.size]
            k += v.size
            phys, note = c.physical(v)
            out.append(
                FittedEffect(
                    c.name,
                    c.where,
                    {p: float(x) for p, x in zip(c.param_names, phys, strict=True)},
                    {p: float(x) for p, x in zip(c.param_names, std, strict=True)},
                    dict(zip(c.param_names, c.units, strict=True)),
                    c.config(v),
                    self.tied_with.get(f"{c.name}@{c.where}", ()),
                    tuple(float(x) for x in v),
                    note,
                )
            )
        return out

    # ----------------------------------------------------------------------------- features, files

    def features(self) -> list[Feature]:
        """The per-sample features the residuals are binned along (:func:`.features.features`)."""
        speed = None
        if self.qd is not None:
            speed = np.linalg.norm(np.einsum("nij,nj->ni", self.joint_position_jacobian(), self.qd), axis=1)
        return features(self.data, self.q, self.nominal, self.gravity_torque(), speed)

    def describe(self) -> dict[str, Any]:
        """The problem as the report gives it (:func:`.stored_model.describe`)."""
        from plugins.model_gap.stored_model import describe

        return describe(self)

    def gap_model_dict(self) -> dict[str, Any]:
        """The augmented model as a mapping (:func:`.stored_model.gap_model_dict`)."""
        from plugins.model_gap.stored_model import gap_model_dict

        return gap_model_dict(self)

    def save_model(self, path: Path) -> Path:
        from plugins.model_gap.stored_model import save_model

        return save_model(self, path)


def checked_noise(model: RobotModel, data: GapData, cfg: ProblemConfig) -> F64:
    """The per-sample noise sigma (m) after the input checks a problem needs (calibration levels, sample
    count, joints, noise, units); raises :class:`GapInputError` saying what is wrong."""
    bad = [c for c in cfg.calibrate if c not in CALIBRATION_LEVELS]
    if bad:
        raise GapInputError(f"unknown calibration level(s) {bad}; use some of {', '.join(CALIBRATION_LEVELS)}")
    if data.n_samples < MIN_SAMPLES:
        raise GapInputError(
            f"{data.n_samples} samples are too few: even the baseline calibration (measurement frame, tool "
            f"point) needs {MIN_SAMPLES}, and naming an effect with cross-validation needs a few dozen"
        )
    if data.n_joints != model.dof:
        raise GapInputError(f"the data have {data.n_joints} joints but model {model.name!r} has {model.dof}")
    if cfg.noise_m is not None:
        if not (np.isfinite(cfg.noise_m) and cfg.noise_m > 0):
            raise GapInputError(f"the noise sigma must be a positive number, got {cfg.noise_m}")
        sigma = np.full(data.n_samples, float(cfg.noise_m))
    elif data.sigma_m is not None:
        sigma = data.sigma_m.copy()
    else:
        raise GapInputError(
            "the measurement noise is needed to tell a gap from noise: give --noise-mm SIGMA (per-axis "
            "1-sigma, e.g. 0.05 for a laser tracker, 0.3 for a Vive tracker) or a sigma_mm column"
        )
    reach = model.chain.reach_bound(skip_groups=("base",))
    spread = float(np.ptp(data.samples.positions, axis=0).max())
    if spread > 20.0 * reach:
        raise GapInputError(
            f"the measured points spread over {spread:.1f} m but {model.name} reaches {reach:.2f} m: "
            "millimetres given as metres?"
        )
    if data.n_samples > 3 and spread < 1e-3 * reach:
        raise GapInputError(f"the measured points span only {spread * 1e3:.3f} mm: metres given as millimetres?")
    return sigma
