"""Models as files: what ``vgr gap`` writes (the augmented model) and reads back.

``vgr gap`` writes every model it builds (``model_0_baseline.yaml``, ``model_<k>_<effect>.yaml``,
``augmented_model.yaml``) as a mapping with ``vgr_gap_model: 1``: the calibrated robot model (its
base is the measurement frame), the effects added with their fitted vector (``values``), their
values in the physical convention (``params``) with one-sigma uncertainties, the effect's
simulator form (``config``), the noise sigma and the calibration. :func:`load_gap_model` reads it
back, as well as a robot model file, a shipped robot name, or the result file of
``vgr calibrate kinematics``.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from engine.plain_data import plain
from plugins.robot.kinematics import RobotModel
from plugins.robot.model_file import load_robot_model, model_to_dict, robot_model_from_dict

if TYPE_CHECKING:
    from .problem import KinematicGapProblem

GAP_MODEL_FORMAT = 1


def describe(problem: KinematicGapProblem) -> dict[str, Any]:
    T = problem.model.T_world_base
    d = problem.data
    values = dict(zip(problem.model.param_names, problem.model.param_values, strict=True))
    nominal = dict(zip(problem.nominal.param_names, problem.nominal.param_values, strict=True))
    return {
        "kind": problem.kind,
        "model": problem.nominal.name,
        "convention": problem.model.convention,
        "data": {
            "source": d.source,
            "n_samples": d.n_samples,
            "columns": sorted(d.columns),
            "sensor": d.sensor,
            "warnings": d.warnings + d.samples.check(),
        },
        "noise_sigma_mm": float(np.median(problem.sigma) * 1e3),
        "noise_source": problem.cfg.noise_source if problem.cfg.noise_m is not None else "data column sigma_mm",
        "calibration": {
            "levels": list(problem.cfg.calibrate),
            "requested": problem.cfg.requested,
            "parameters": list(problem.base_names),
            "notes": problem.calibration_notes,
            "T_meas_base": T.tolist(),
            "tool_point_flange_mm": (problem.model.T_flange_tcp[:3, 3] * 1e3).tolist(),
            "joint_parameter_changes": {
                n: values[n] - nominal.get(n, 0.0)
                for n in problem.base_names
                if n.startswith("joint") and n in values and n in nominal
            },
        },
    }


def gap_model_dict(problem: KinematicGapProblem) -> dict[str, Any]:
    """The augmented model as a mapping (see :func:`save_model`)."""
    fitted = {fe.representative: fe for fe in problem.fitted_effects()} if problem.accepted else {}
    effects = []
    for c, v in problem.accepted:
        label = f"{c.name}@{c.where}"
        fe = fitted[label]
        entry = {
            "name": c.name,
            "where": c.where,
            "side": c.side,
            "params": fe.params,  # physical convention (a backlash is a play >= 0)
            "param_std": fe.param_std,
            "units": fe.units,
            "values": [float(x) for x in v],  # what the model fits (a sign convention included)
            "config": c.config(v),
        }
        if fe.note:
            entry["note"] = fe.note
        others = problem.tied_with.get(label)
        if others:  # a tie term: evaluated as this effect, standing for the whole group
            members = sorted({label, *others})
            entry["tied_with"] = list(others)
            entry["tie"] = {
                "label": "|".join(members),
                "note": f"tie term: the data could not tell {' and '.join(members)} apart; it is evaluated as "
                f"{label} (the same prediction within the decision margin), which is not a claim that {label} "
                "is the cause",
            }
        effects.append(entry)
    return {
        "vgr_gap_model": GAP_MODEL_FORMAT,
        "description": "robot model augmented by `vgr gap`: calibrated geometry (base = the measurement "
        "frame) and the effects the data needed, with one-sigma uncertainties (SI units)",
        "robot": model_to_dict(problem.model),
        "effects": effects,
        "noise_sigma_m": float(np.median(problem.sigma)),
        "calibration": {"levels": list(problem.cfg.calibrate), "parameters": list(problem.base_names)},
    }


def save_model(problem: KinematicGapProblem, path: Path) -> Path:
    path = Path(path)
    path.write_text(yaml.safe_dump(plain(gap_model_dict(problem)), sort_keys=False), encoding="utf-8")
    return path


def effect_config(effect: Any) -> dict[str, Any]:
    """A catalog effect as the plain mapping ``effects_from_config`` reads (lists for tuples)."""
    return plain(asdict(effect))


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
