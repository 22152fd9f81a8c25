"""One call from a model and data to a model-gap result (what ``vgr gap`` and the stage run)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rich.console import Console

from engine.gap import GapConfig, GapInputError, GapResult, run_gap
from engine.gap.files import write_report
from engine.gap.noise import estimate_noise_scale
from engine.gap.report import render
from engine.gap.workflow import collect_candidates
from plugins.robot.kinematics import RobotModel
from plugins.robot.model_file import load_robot_model, robot_model_from_dict

from .data import GapData, load_gap_data
from .problem import KinematicGapProblem, ProblemConfig


def families_from_registry(extra_modules: tuple[str, ...] = ()) -> list[Any]:
    """The effect families every loaded plugin contributes through ``vgr_model_effects``."""
    from engine.plugin_manager import load_registry

    registry = load_registry(extra_modules)
    return [f() if isinstance(f, type) else f for _, f in sorted(registry.effects.items())]


def load_gap_model(model: str | Path | RobotModel) -> tuple[RobotModel, list[dict[str, Any]]]:
    """A shipped robot name, a robot model file, or an augmented model written by ``vgr gap``.

    Returns the robot model and the effects of an augmented model (empty otherwise).
    """
    if isinstance(model, RobotModel):
        return model, []
    path = Path(str(model))
    if path.suffix in (".yaml", ".yml") and path.is_file():
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except yaml.YAMLError as e:
            raise ValueError(f"model file {path} is not valid YAML: {e}") from None
        if isinstance(data, dict) and "vgr_gap_model" in data:
            return robot_model_from_dict(data.get("robot"), source=str(path)), list(data.get("effects") or [])
    return load_robot_model(model), []


def estimate_noise(robot: RobotModel, data: GapData, calibrate: tuple[str, ...], families: list[Any]) -> float:
    """Per-axis noise sigma (m) estimated from the data (:func:`engine.gap.noise.estimate_noise_scale`)."""
    provisional = 1e-3
    problem = KinematicGapProblem(robot, data, ProblemConfig(calibrate, noise_m=provisional))
    scale, _ = estimate_noise_scale(problem.linearise(), collect_candidates(problem, families), problem)
    if not scale > 0:
        raise GapInputError("the data fit the model exactly: cannot estimate the noise, give --noise-mm")
    return provisional * scale


def analyse_gap(
    model: str | Path | RobotModel,
    data: str | Path | GapData,
    *,
    noise_mm: float | None = None,
    calibrate: tuple[str, ...] = ("frame", "tool"),
    report_dir: str | Path | None = None,
    config: GapConfig | None = None,
    families: list[Any] | None = None,
    console: Console | None = None,
    data_options: dict[str, Any] | None = None,
) -> GapResult:
    """Run the model-gap workflow; write ``report_dir`` (JSON, figures, model files) if given.

    ``noise_mm`` (per-axis 1-sigma): when neither it nor a ``sigma_mm`` data column is given, the noise
    is estimated from the data (:func:`estimate_noise`) and the report says so.
    """
    robot, initial = load_gap_model(model)
    gap_data = data if isinstance(data, GapData) else load_gap_data(data, **(data_options or {}))
    fams = families if families is not None else families_from_registry()
    if noise_mm is None and gap_data.sigma_m is None:
        noise_m, source = estimate_noise(robot, gap_data, tuple(calibrate), fams), "estimated"
    else:
        noise_m, source = (None if noise_mm is None else float(noise_mm) / 1e3), "given"
    problem = KinematicGapProblem(
        robot, gap_data, ProblemConfig(tuple(calibrate), noise_m=noise_m, noise_source=source)
    )
    if initial:
        by_label = {(c.name, c.where): c for c in collect_candidates(problem, fams) if not c.unavailable}
        for e in initial:
            cand = by_label.get((e.get("name"), e.get("where")))
            if cand is None:
                raise GapInputError(
                    f"the model's effect {e.get('name')}@{e.get('where')} cannot be applied to these data"
                )
            values = np.array([float(e["params"][p]) for p in cand.param_names])
            problem.add_effect(cand, values, tied_with=tuple(e.get("tied_with") or ()))  # a tie term stays one
    result = run_gap(problem, fams, config, model_dir=report_dir)
    if report_dir is not None:
        out = Path(report_dir)
        result.files["augmented_model"] = str(problem.save_model(out / "augmented_model.yaml"))
        write_report(result, problem.features(), out)
    if console is not None:
        render(result, console)
    return result
