"""One call from a model and data to a model-gap result (what ``vgr gap`` and the stage run)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from plugins.model_gap.core import GapConfig, GapInputError, GapResult, run_gap
from plugins.model_gap.core.files import write_report
from plugins.model_gap.core.noise import estimate_noise_scale
from plugins.model_gap.core.report import render
from plugins.model_gap.core.robust import robust_scale
from plugins.model_gap.core.workflow import collect_candidates, samples_needed
from plugins.model_gap.data import GapData
from plugins.model_gap.families import families_from_registry
from plugins.model_gap.inputs import load_gap_data
from plugins.model_gap.problem import DEFAULT_CALIBRATION, KinematicGapProblem, ProblemConfig
from plugins.model_gap.robust_fit import run_screened
from plugins.model_gap.stored_model import load_stored_model
from plugins.robot.kinematics import RobotModel

PROVISIONAL_NOISE_M = 1e-3  # whitening scale while the noise is still to be estimated (the fit does not use it)


def estimate_noise(problem: KinematicGapProblem, families: list[Any]) -> float:
    """Per-axis noise sigma (m) estimated from the data (:func:`plugins.model_gap.core.noise.estimate_noise_scale`).

    When the campaign is too small to fit every candidate at once (a 40-pose campaign), the residual
    scale of the baseline calibration alone is taken instead (robust, :func:`.core.robust.robust_scale`),
    and a calibration note says so: an over-estimate when an effect is present, so the noise floor and
    the held-out ratio to it are then optimistic; the verdict does not use it.
    """
    lin = problem.linearise()
    try:
        scale, _ = estimate_noise_scale(lin, collect_candidates(problem, families), problem)
    except GapInputError as e:
        if lin.residual.size - lin.jacobian.shape[2] < 30:
            raise
        scale = robust_scale(lin.residual, lin.jacobian.shape[2])
        problem.calibration_notes.append(
            f"the noise was estimated from the baseline calibration's residuals ({e}); an over-estimate when "
            "an effect is present: give --noise-mm for the noise floor to mean something"
        )
    if not scale > 0:
        raise GapInputError("the data fit the model exactly: cannot estimate the noise, give --noise-mm")
    return float(np.median(problem.sigma)) * scale


def build_problem(
    robot: RobotModel,
    data: GapData,
    *,
    noise_mm: float | None = None,
    calibrate: tuple[str, ...] | None = None,
    config: GapConfig | None = None,
    families: list[Any] | None = None,
    tool_points: dict[str, list[float]] | None = None,
) -> KinematicGapProblem:
    """The kinematic gap problem with its baseline calibration and noise.

    ``calibrate`` None is the default, the full calibration the data identify
    (:data:`~.problem.DEFAULT_CALIBRATION`: measurement frame, tool, joint geometry; parameters the data
    cannot identify stay at their values and the report says which). When the data cannot carry the
    joint geometry at all -- fewer samples than the workflow needs with it, or a joint calibration
    that fails -- the frame and the tool are calibrated alone and the report says why. Explicit levels
    are taken as given. The noise is ``noise_mm`` (per axis), else the data's ``sigma_mm`` column,
    else estimated (:func:`estimate_noise`). ``tool_points``: several measured points' offsets a stored
    model knows (the start of their fit, or the points themselves when the tool is not calibrated).
    """
    cfg = config or GapConfig()
    fams = families if families is not None else families_from_registry()
    estimated = noise_mm is None and data.sigma_m is None
    noise_m = PROVISIONAL_NOISE_M if estimated else (None if noise_mm is None else float(noise_mm) / 1e3)

    def make(levels: tuple[str, ...], requested: str) -> KinematicGapProblem:
        source = "estimated" if estimated else "given"
        cfg = ProblemConfig(levels, noise_m=noise_m, noise_source=source, requested=requested, tool_points=tool_points)
        return KinematicGapProblem(robot, data, cfg)

    if calibrate is not None:
        problem = make(tuple(calibrate), ",".join(calibrate) or "none")
    else:
        problem = make(DEFAULT_CALIBRATION, "default")
        need = samples_needed(len(problem.base_names), collect_candidates(problem, fams), 3, cfg)
        why = problem.joint_calibration_failed
        if why is None and data.n_samples < need:
            why = (
                f"{data.n_samples} samples are too few for it ({len(problem.base_names)} calibration parameters "
                f"need {need} with {cfg.selection.cv_folds}-fold cross-validation)"
            )
        if why is not None:
            problem = make(("frame", "tool"), "default")
            problem.calibration_notes.insert(
                0,
                "the joint geometry was not calibrated, only the measurement frame and the tool: "
                + why
                + "; joint zero and length errors are then tested as effects",
            )
    if estimated:
        problem.set_noise(estimate_noise(problem, fams), "estimated")
    return problem


def _apply_stored_effects(problem: KinematicGapProblem, initial: list[dict[str, Any]], fams: list[Any]) -> None:
    """Put a stored (augmented) model's effects into the problem, refitted with the baseline."""
    if not initial:
        return
    by_label = {(c.name, c.where): c for c in collect_candidates(problem, fams) if not c.unavailable}
    for e in initial:
        cand = by_label.get((e.get("name"), e.get("where")))
        if cand is None:
            raise GapInputError(f"the model's effect {e.get('name')}@{e.get('where')} cannot be applied to these data")
        stored = e.get("values")  # the fitted vector; older files: the params are that vector
        vec = [float(x) for x in stored] if stored else [float(e["params"][p]) for p in cand.param_names]
        problem.add_effect(cand, np.array(vec), tied_with=tuple(e.get("tied_with") or ()))  # a tie term stays one


def analyse_gap(
    model: str | Path | RobotModel,
    data: str | Path | GapData,
    *,
    noise_mm: float | None = None,
    calibrate: tuple[str, ...] | None = None,
    report_dir: str | Path | None = None,
    config: GapConfig | None = None,
    families: list[Any] | None = None,
    console: Console | None = None,
    data_options: dict[str, Any] | None = None,
) -> GapResult:
    """Run the model-gap workflow; write ``report_dir`` (JSON, figures, model files) if given.

    ``calibrate`` None: the default baseline, the full calibration the data identify
    (:func:`build_problem`). ``noise_mm`` (per-axis 1-sigma): when neither it nor a ``sigma_mm`` data
    column is given, the noise is estimated from the data (:func:`estimate_noise`) and the report says so.
    Gross errors are screened out first and again with the final model (:mod:`.robust_fit`; the
    config's ``outlier_alpha``, 0 to run on every sample).
    """
    if isinstance(model, RobotModel):
        robot, initial, points = model, [], None
    else:  # a robot, or a model vgr wrote (augmented: its effects are applied first; calibrated)
        stored = load_stored_model(model)
        robot, initial, points = stored.robot, stored.effects, stored.tool_points
    gap_data = data if isinstance(data, GapData) else load_gap_data(data, **(data_options or {}))
    fams = families if families is not None else families_from_registry()
    cfg = config or GapConfig()

    def build(d: GapData) -> KinematicGapProblem:
        problem = build_problem(
            robot, d, noise_mm=noise_mm, calibrate=calibrate, config=cfg, families=fams, tool_points=points
        )
        _apply_stored_effects(problem, initial, fams)
        return problem

    def run(problem: KinematicGapProblem, model_dir: Path | None) -> GapResult:
        return run_gap(problem, fams, cfg, model_dir=model_dir)

    out_dir = None if report_dir is None else Path(report_dir)
    result, problem = run_screened(gap_data, build, run, fams, cfg.outlier_alpha, out_dir)
    if report_dir is not None:
        out = Path(report_dir)
        result.files["augmented_model"] = str(problem.save_model(out / "augmented_model.yaml"))
        write_report(result, problem.features(), out)
    if console is not None:
        render(result, console)
    return result
