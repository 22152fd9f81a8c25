"""Kinematic (geometric) calibration of a serial robot from external measurements of its tool.

Method (seed 003, made complete): the robot is parameterised in standard DH, modified DH or POE
(:mod:`plugins.robot.conventions`; every geometric quantity is a named chain parameter), together with
the unknown measurement frame (the robot base in the tracker/camera frame, 6 parameters) and the
measured tool point in the flange frame (3 parameters; 6 with orientation data). The analytic
Jacobian is the screw Jacobian of the chain (seed 003's formulas 14.14-14.18 generalised: each
parameter is a "virtual joint"). Steps:

1. initial measurement frame by a rigid fit (``Rotation.align_vectors``) of the nominal predictions
   to the measurements;
2. identifiability analysis at the initial estimate (:mod:`.identifiability`): redundant parameters
   are fixed, confounded combinations named, and the data's rank compared with the structural rank
   of the parameterisation (a rich random pose set) to detect poses that do not excite the model;
3. Levenberg-Marquardt with step limiting (:mod:`.lm`) on the whitened residuals (position noise
   ``noise_position_m`` per axis; orientation noise ``noise_rotation_rad``);
4. covariance ``s^2 (J^T J)^-1`` of the identified parameters (``s^2`` the a-posteriori variance
   factor unless ``trust_noise``), per-sample residuals, outlier flags (chi-square 99.99 %), a
   before/after table on held-out poses, an optional convergence plot, and a verdict.

The returned :class:`CalibrationResult` holds the calibrated model as a model-file mapping in
``estimate["model_file"]`` (``plugins.robot.model_file.robot_model_from_dict`` rebuilds it) and the
measurement frame as ``estimate["T_meas_base"]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from engine.transforms import so3_left_jacobian_inv
from plugins.calibration.kinematics.data import KinematicSamples
from plugins.calibration.kinematics.frames import _analysis_model, initial_frames
from plugins.calibration.kinematics.identifiability import Identifiability, analyse
from plugins.calibration.kinematics.lm import LMResult, levenberg_marquardt
from plugins.calibration.kinematics.points import ToolPoints, first_point, fit_point_offsets, split_names
from plugins.calibration.result import CalibrationResult
from plugins.robot.kinematics import RobotModel
from plugins.robot.model_file import model_to_dict

F64 = NDArray[np.float64]

_JOINT_PARAMS = {
    "dh": ("theta", "d", "a", "alpha", "beta"),
    "mdh": ("alpha", "a", "beta", "theta", "d"),
    "poe": ("tx", "ty", "tz", "rx", "ry", "theta"),
}


@dataclass
class KinematicCalibrationConfig:
    """Options of :func:`calibrate_kinematics` (SI units)."""

    parameterisation: Literal["dh", "mdh", "poe"] | None = None  # default: the model's convention
    estimate_base: bool = True  # unknown measurement frame (T_meas_base)
    estimate_tool: bool = True  # unknown tool point (and orientation with full-pose data)
    noise_position_m: float = 5e-5  # per axis, one sigma
    noise_rotation_rad: float = 1e-4
    trust_noise: bool = False  # covariance from the given noise instead of the residual variance
    identifiability_tol: float = 1e-6
    max_iterations: int = 30
    plausible_offset_m: float = 0.01  # joint parameters moving further than this are reported
    plausible_offset_rad: float = np.radians(2.0)
    max_step_m: float = 0.05  # LM step limit: change of the predictions per iteration
    holdout_fraction: float = 0.25  # used when no held-out samples are given
    rng_seed: int = 0
    structural_poses: int = 300


@dataclass
class KinematicCalibration:
    """Everything a calibration produced; ``result`` is the common :class:`CalibrationResult`."""

    result: CalibrationResult
    model: RobotModel  # calibrated
    initial_model: RobotModel  # nominal geometry + initial measurement frame
    identifiability: Identifiability
    structural: Identifiability
    lm: LMResult
    table: list[dict] = field(default_factory=list)  # before/after rows (mm, deg)
    points: ToolPoints | None = None  # several measured points: their offsets (the model's tool is the first)


# --------------------------------------------------------------------------- problem


class _Problem:
    """Residuals and Jacobian of the kept parameters around ``model``'s current values.

    ``names`` may hold point parameters (``tool[k].t*``, several measured points: :mod:`.points`):
    ``x`` then moves ``points``' offsets too, and every row is evaluated at its own point.
    """

    def __init__(
        self, model: RobotModel, samples: KinematicSamples, names: list[str], cfg, points: ToolPoints | None = None
    ) -> None:
        self.model = model
        self.samples = samples
        self.names = names
        self.chain_pos, self.point_pos = split_names(names)
        self.idx = [model.chain.index(names[i]) for i in self.chain_pos]
        self.v0 = model.param_values.copy()
        self.points = points
        self.sp = cfg.noise_position_m
        self.sr = cfg.noise_rotation_rad

    def values(self, x: F64) -> F64:
        """The chain's values (``(P,)``: the model's own, the first point's tool) at ``x``."""
        v = self.v0.copy()
        v[self.idx] += np.asarray(x)[self.chain_pos]
        return v

    def points_at(self, x: F64) -> ToolPoints | None:
        """The measured points' offsets at ``x``."""
        if self.points is None or not self.point_pos:
            return self.points
        return self.points.with_offsets(self.points.flat() + np.asarray(x)[self.point_pos])

    def sample_values(self, x: F64) -> F64:
        """The values each sample is evaluated at (``(N, P)`` with several points)."""
        pts = self.points_at(x)
        return self.values(x) if pts is None else pts.values(self.model, self.values(x), self.samples)

    def residuals(self, x: F64) -> tuple[F64, F64]:
        """Unwhitened residuals (N, 3) positions [m] and (N, 3) rotation vectors [rad] (or None)."""
        T = self.model.fk(self.samples.q, self.sample_values(x))
        rp = self.samples.positions - T[:, :3, 3]
        if not self.samples.full_pose:
            return rp, None
        rr = Rotation.from_matrix(self.samples.rotations @ np.swapaxes(T[:, :3, :3], 1, 2)).as_rotvec()
        return rp, rr

    def __call__(self, x: F64) -> tuple[F64, F64]:
        """Whitened residual vector and its Jacobian w.r.t. x."""
        T, Jall = self.model.param_jacobian(self.samples.q, self.sample_values(x), frame="base")
        J = np.zeros((Jall.shape[0], 6, len(self.names)))
        J[:, :, self.chain_pos] = Jall[:, :, self.idx]
        pts = self.points_at(x)
        if self.point_pos and pts is not None:
            J[:, :, self.point_pos] = pts.columns(Jall, self.model, self.samples)
        rp = (self.samples.positions - T[:, :3, 3]) / self.sp
        Jp = -J[:, :3] / self.sp
        if not self.samples.full_pose:
            return rp.ravel(), Jp.reshape(-1, len(self.names))
        phi = Rotation.from_matrix(self.samples.rotations @ np.swapaxes(T[:, :3, :3], 1, 2)).as_rotvec()
        Jr = np.stack([-so3_left_jacobian_inv(-p) @ Jw for p, Jw in zip(phi, J[:, 3:], strict=True)])
        r = np.concatenate([rp, phi / self.sr], axis=1).ravel()
        Jall = np.concatenate([Jp, Jr / self.sr], axis=1).reshape(-1, len(self.names))
        return r, Jall


def candidate_parameters(model: RobotModel, full_pose: bool, cfg: KinematicCalibrationConfig) -> list[str]:
    """Parameters to estimate, in identifiability priority order: base, tool, joints outwards.

    The measurement frame and the tool come first, so that joint parameters equivalent to them (joint
    1's zero and height, the last joint's offsets) are the ones fixed at their nominal values: the
    estimated joint parameters then mean the same thing whatever the data's frames were.
    """
    names: list[str] = []
    if cfg.estimate_base:
        names += [f"base.{k}" for k in ("tx", "ty", "tz", "rx", "ry", "rz")]
    if cfg.estimate_tool:
        tool = ("tx", "ty", "tz", "rx", "ry", "rz") if full_pose else ("tx", "ty", "tz")
        names += [f"tool.{k}" for k in tool]
    for j in range(1, model.dof + 1):
        names += [f"joint{j}.{k}" for k in _JOINT_PARAMS[model.convention]]
    return names


def _random_configs(model: RobotModel, n: int, seed: int) -> F64:
    lo, hi = np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi)
    return lo + np.random.default_rng(seed).random((n, model.dof)) * (hi - lo)


def expected_holdout_rms(
    model: RobotModel,
    holdout: KinematicSamples,
    names: list[str],
    cov: F64,
    sigma_m: float,
    points: ToolPoints | None = None,
) -> tuple[float, float]:
    """Expected 3-D position RMS on held-out poses for a correct model, and its degrees of freedom.

    A held-out error is the new measurement's noise minus the calibrated model's prediction error,
    ``e_i = n_i - A_i d`` (``A_i`` the position Jacobian of the identified parameters, ``d`` their
    error, covariance ``cov``), so ``E|e_i|^2 = 3 sigma^2 + tr(A_i cov A_i^T)``: the noise floor
    raised by what the fit left uncertain. Averaged over poses like the calibration ones this is
    ``3 sigma^2 (1 + p / n)`` for ``p`` parameters and ``n`` residuals; here it is computed exactly
    for the given poses. Returns ``(sqrt(mean E|e_i|^2), dof)`` with ``dof`` Satterthwaite's degrees
    of freedom of the held-out mean square, ``(tr S)^2 / tr(S^2)`` for ``S = sigma^2 I + A cov A^T``:
    ``(RMS / expected)^2`` then follows ``chi2(dof) / dof`` (``F(dof, nu)`` when ``sigma`` and ``cov``
    rest on a variance estimated with ``nu`` degrees of freedom).
    """
    cfg = KinematicCalibrationConfig(noise_position_m=1.0)
    _, J = _Problem(model, holdout, names, cfg, points)(np.zeros(len(names)))
    A = -J.reshape(holdout.n_samples, -1, len(names))[:, :3, :].reshape(-1, len(names))
    m = A.shape[0]
    M = cov @ (A.T @ A)  # tr(A cov A^T) = tr(M), tr((A cov A^T)^2) = tr(M^2)
    tr_s = m * sigma_m**2 + float(np.trace(M))
    tr_s2 = m * sigma_m**4 + 2.0 * sigma_m**2 * float(np.trace(M)) + float(np.sum(M * M.T))
    return float(np.sqrt(tr_s / holdout.n_samples)), tr_s**2 / tr_s2


def _error_rows(model: RobotModel, samples: KinematicSamples, points: ToolPoints | None = None) -> dict[str, float]:
    T = model.fk(samples.q, None if points is None else points.values(model, None, samples))
    e = (samples.positions - T[:, :3, 3]) * 1e3
    row = {
        "rms_mm": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
        "max_mm": float(np.linalg.norm(e, axis=1).max()),
        "rms_x_mm": float(np.sqrt(np.mean(e[:, 0] ** 2))),
        "rms_y_mm": float(np.sqrt(np.mean(e[:, 1] ** 2))),
        "rms_z_mm": float(np.sqrt(np.mean(e[:, 2] ** 2))),
    }
    if samples.full_pose:
        rr = Rotation.from_matrix(samples.rotations @ np.swapaxes(T[:, :3, :3], 1, 2)).magnitude()
        row["rms_rot_deg"] = float(np.degrees(np.sqrt(np.mean(rr**2))))
    return row


# --------------------------------------------------------------------------- main entry point


def calibrate_kinematics(
    model: RobotModel,
    samples: KinematicSamples,
    *,
    holdout: KinematicSamples | None = None,
    config: KinematicCalibrationConfig | None = None,
) -> KinematicCalibration:
    """Calibrate ``model``'s geometry, measurement frame and tool from ``samples``.

    Raises ValueError for malformed input (wrong number of joints, NaN, bad rotations); a calibration
    that cannot be trusted comes back with verdict ``degenerate`` or ``failed`` and reasons.
    """
    cfg = config or KinematicCalibrationConfig()
    if samples.n_joints != model.dof:
        raise ValueError(f"samples have {samples.n_joints} joints, model {model.name!r} has {model.dof}")
    if holdout is not None and holdout.n_joints != model.dof:
        raise ValueError(f"held-out samples have {holdout.n_joints} joints, model has {model.dof}")
    if not (cfg.noise_position_m > 0 and cfg.noise_rotation_rad > 0):
        raise ValueError("noise levels must be positive")
    reasons = samples.check()
    advice: list[str] = []
    if holdout is None and cfg.holdout_fraction > 0 and samples.n_samples >= 8:
        perm = np.random.default_rng(cfg.rng_seed).permutation(samples.n_samples)
        n_hold = max(1, round(cfg.holdout_fraction * samples.n_samples))
        holdout, samples = samples.subset(np.sort(perm[:n_hold])), samples.subset(np.sort(perm[n_hold:]))
    spread = float(np.ptp(samples.positions, axis=0).max())
    reach = model.chain.reach_bound(skip_groups=("base",))
    if spread > 20.0 * reach:
        raise ValueError(
            f"measured positions spread over {spread:.1f} m but {model.name} reaches {reach:.2f} m: "
            "they look like millimetres given as metres"
        )
    conv = cfg.parameterisation or model.convention
    work = model.to_convention(conv)
    points = ToolPoints.of(samples)
    if points is None:
        work = initial_frames(work, samples, cfg.estimate_base, cfg.estimate_tool)
    else:  # frame and the first point from the first point's rows, then each other point's offset
        if samples.full_pose or not cfg.estimate_tool:
            raise ValueError("several measured points (a point column) need position data and the tool estimated")
        work = initial_frames(work, first_point(samples, points), cfg.estimate_base, True)
        points = fit_point_offsets(work, samples, points)
    initial, initial_points = work, points
    names = candidate_parameters(work, samples.full_pose, cfg)
    if points is not None:  # right after the tool: a point offset is kept before a joint parameter
        at_tool = max(i for i, n in enumerate(names) if n.startswith("tool.")) + 1
        names = names[:at_tool] + points.param_names() + names[at_tool:]
    # Identifiability is analysed at the nominal joint geometry, where structural redundancies are
    # exact (at calibrated values they become near-redundancies that only slow the solver down).
    # A nominal tool point on the last joint axis hides that axis, so after solving, the analysis is
    # repeated with the estimated tool point until the identifiable set is stable.
    history: list[dict] = []
    kept: list[str] = []
    lm: LMResult | None = None
    at = initial
    for _ in range(3):
        J_at = _Problem(at, samples, names, cfg, points)(np.zeros(len(names)))[1]
        ident = analyse(J_at, names, cfg.identifiability_tol)
        if lm is not None and ident.kept == kept:
            break
        kept = ident.kept
        step_problem = _Problem(work, samples, kept, cfg, points)
        lm = levenberg_marquardt(
            step_problem,
            np.zeros(len(kept)),
            max_iterations=cfg.max_iterations,
            max_step=cfg.max_step_m / cfg.noise_position_m,
        )
        offset = len(history) - 1 if history else 0
        history += [h | {"iteration": h["iteration"] + offset} for h in lm.history[(1 if history else 0) :]]
        work = work.with_values(step_problem.values(lm.x))
        points = step_problem.points_at(lm.x)
        if not lm.converged:
            break
        at = _analysis_model(initial, work, samples.q)
    assert lm is not None
    lm.history = history
    lm.iterations = history[-1]["iteration"]
    calibrated = work
    q_rich = _random_configs(at, cfg.structural_poses, cfg.rng_seed + 1)
    T_rich = at.fk(q_rich)
    labels = None if points is None else np.array(points.names)[np.arange(len(q_rich)) % len(points.names)]
    rich = KinematicSamples(q_rich, T_rich[:, :3, 3], T_rich[:, :3, :3] if samples.full_pose else None, point=labels)
    structural = analyse(
        _Problem(at, rich, names, cfg, points)(np.zeros(len(names)))[1], names, cfg.identifiability_tol
    )
    kept_problem = _Problem(work, samples, kept, cfg, points)
    r, J = kept_problem(np.zeros(len(kept)))
    verdict = "ok"
    if ident.dropped:
        reasons.append(
            f"{len(ident.dropped)} of {len(names)} parameters not identifiable, fixed at nominal: "
            + "; ".join(ident.describe_dropped())
        )
    missing = [n for n in structural.kept if n not in kept]
    if missing:
        verdict = "degenerate"
        reasons.append(f"the poses do not excite {', '.join(missing)} (identifiable with other poses)")
        advice.append("add poses that move the joints named above over a wide range (tens of degrees)")
    if r.size <= len(kept):
        verdict = "degenerate"
        reasons.append(f"{r.size} residuals for {len(kept)} unknowns: add poses")
    dof = max(1, r.size - len(kept))
    s2 = 1.0 if cfg.trust_noise else float(r @ r) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)  # J is whitened, so this is in SI units
    except np.linalg.LinAlgError:
        cov = None
        verdict = "degenerate"
        reasons.append("normal matrix singular at the solution")
    rp, rr = kept_problem.residuals(np.zeros(len(kept)))
    residuals = rp if rr is None else np.concatenate([rp, rr], axis=1)
    names_res = ["x", "y", "z"] + (["rx", "ry", "rz"] if rr is not None else [])
    d2 = np.sum((rp / cfg.noise_position_m) ** 2, axis=1) / s2
    outliers = d2 > chi2.ppf(0.9999, 3)
    chi2_stat = float(r @ r)
    consistent = chi2_stat <= chi2.ppf(0.999, dof)
    if not lm.converged:
        verdict = "failed"
        reasons.append(f"Levenberg-Marquardt: {lm.message}")
    rms_cal_mm = float(np.sqrt(np.mean(np.sum(rp**2, axis=1)))) * 1e3
    if rms_cal_mm > 100.0:
        verdict = "failed"
        reasons.append(f"residual RMS {rms_cal_mm:.1f} mm after calibration: wrong model, joint order or units")
    implausible = []
    for n in kept:
        if not n.startswith("joint"):
            continue
        i = work.chain.index(n)
        d = float(calibrated.param_values[i] - initial.param_values[i])
        limit = cfg.plausible_offset_m if work.chain.param_kind(n) == "length" else cfg.plausible_offset_rad
        if abs(d) > limit:
            implausible.append(
                f"{n} {d * 1e3:+.1f} mm" if work.chain.param_kind(n) == "length" else f"{n} {np.degrees(d):+.2f} deg"
            )
    if implausible:
        reasons.append(
            "joint parameters moved far beyond manufacturing tolerances: "
            + ", ".join(implausible)
            + " (wrong robot model, joint order or joint sign?)"
        )
        advice.append("check that the model and the joint angle convention match the robot that was measured")
    if verdict == "ok" and (np.any(outliers) or not consistent or implausible):
        verdict = "warning"
    if np.any(outliers):
        reasons.append(f"{int(outliers.sum())} outlier samples (residual beyond the 99.99 % chi-square bound)")
    if not consistent:
        reasons.append(
            f"residuals ({np.sqrt(chi2_stat / dof) * cfg.noise_position_m * 1e3:.3f} mm per axis, with dof = "
            f"residuals - parameters) "
            f"exceed the stated noise ({cfg.noise_position_m * 1e3:.3f} mm): unmodelled effects remain "
            "(see vgr gap)"
        )
    table = []
    for label, data in (("calibration", samples), ("held-out", holdout)):
        if data is None:
            continue
        before, after = _error_rows(initial, data, initial_points), _error_rows(calibrated, data, points)
        table.append({"set": label, "n": data.n_samples, "before": before, "after": after})
    metrics = {
        "rms_before_mm": table[0]["before"]["rms_mm"],
        "rms_after_mm": table[0]["after"]["rms_mm"],
        "observability_o1": ident.observability_o1,
        "condition_number": ident.condition_number,
        "n_params_identified": float(len(kept)),
        "n_params_dropped": float(len(ident.dropped)),
        "sigma_position_mm": float(np.sqrt(s2)) * cfg.noise_position_m * 1e3,
        "chi2": chi2_stat,
        "chi2_dof": float(dof),
    }
    if not cfg.trust_noise:
        metrics["covariance_dof"] = float(dof)  # s^2 estimated: confidence regions use F(k, dof)
    if len(table) > 1:
        metrics["holdout_rms_before_mm"] = table[1]["before"]["rms_mm"]
        metrics["holdout_rms_after_mm"] = table[1]["after"]["rms_mm"]
        if cov is not None and holdout is not None:
            sigma = np.sqrt(s2) * cfg.noise_position_m
            expected, h_dof = expected_holdout_rms(calibrated, holdout, kept, cov, sigma, points)
            metrics["holdout_rms_expected_mm"] = expected * 1e3
            metrics["holdout_rms_dof"] = h_dof
            table[1]["expected_rms_mm"] = expected * 1e3
    values = calibrated.param_values
    moved = {n: float(values[work.chain.index(n)] - initial.param_values[work.chain.index(n)]) for n in kept
             if n in work.param_names}  # fmt: skip
    if points is not None and initial_points is not None:  # a point's offset from the first point moved too
        moved |= dict(zip(points.param_names(), (points.flat() - initial_points.flat()).tolist(), strict=True))
    estimate = {
        "T_meas_base": calibrated.T_world_base,
        "T_flange_tcp": calibrated.T_flange_tcp,
        "offsets": {n: moved[n] for n in kept},
        "model_file": model_to_dict(calibrated),
    }
    if points is not None:  # every measured point on the flange (the model's own tool is the first)
        estimate["tool_points"] = points.flange_points(calibrated)
        estimate["tool_point_offsets"] = points.as_dict()  # what ToolPoints.of(samples, known) rebuilds
    result = CalibrationResult(
        kind="kinematic",
        verdict=verdict,  # type: ignore[arg-type]
        estimate=estimate,
        param_names=kept,
        covariance=cov,
        residuals=residuals,
        residual_names=names_res,
        outliers=outliers,
        reasons=reasons,
        advice=advice,
        metrics=metrics,
        method=f"levenberg-marquardt, {conv} parameters, {'pose' if samples.full_pose else 'position'} data",
        iterations=lm.iterations,
    )
    return KinematicCalibration(result, calibrated, initial, ident, structural, lm, table, points)
