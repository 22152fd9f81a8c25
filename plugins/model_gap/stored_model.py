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

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml

from engine.plain_data import plain, read_document
from plugins.robot.kinematics import RobotModel
from plugins.robot.model_file import load_robot_model, model_to_dict, robot_model_from_dict


class KinematicGapProblem(Protocol):
    """What the writers below read of a plugins.model_gap.problem.KinematicGapProblem, named here so
    that this module does not import the problem that calls it (the problem's describe,
    gap_model_dict and save_model methods are these functions)."""

    kind: str
    model: RobotModel
    nominal: RobotModel
    data: Any
    cfg: Any
    sigma: np.ndarray
    base_names: list[str]
    calibration_notes: list[str]
    accepted: list[tuple[Any, np.ndarray]]
    tied_with: dict[str, Any]
    points: Any
    axis_names: tuple[str, ...]
    n_samples: int

    def fitted_effects(self) -> list[Any]: ...


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
        "noise_source": problem.cfg.noise_source,
        # several measured points: each one's offset from the first (the robot's own tool point)
        "tool_points": None if problem.points is None else problem.points.as_dict(),
        "calibration": {"levels": list(problem.cfg.calibrate), "parameters": list(problem.base_names)},
        # the size of the fit: a new measurement's expected error is the noise raised by sqrt(1 + p / n)
        "fit": {
            "n_samples": problem.n_samples,
            "n_residuals": int(problem.n_samples * len(problem.axis_names)),
            "n_parameters": len(problem.base_names) + sum(int(v.size) for _, v in problem.accepted),
        },
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
        data = read_document(path, "yaml", "model file")
        if isinstance(data, dict) and "vgr_gap_model" in data:
            return robot_model_from_dict(data.get("robot"), source=str(path)), list(data.get("effects") or [])
    return load_robot_model(model), []


@dataclass
class StoredModel:
    """A model file vgr wrote, as ``vgr gap check`` scores it (see :func:`load_stored_model`)."""

    robot: RobotModel  # its base is the measurement frame (a calibrated or augmented model)
    effects: list[dict[str, Any]]  # the augmented model's effects (model-file entries)
    kind: str  # gap model | kinematic calibration | robot model
    source: str
    noise_sigma_m: float | None = None  # the noise the model was fitted with (per axis)
    tool_points: dict[str, list[float]] | None = None  # several measured points: offsets from the first
    n_parameters: int | None = None  # how many parameters its fit had, on how many residuals
    n_residuals: int | None = None

    @property
    def expected_factor(self) -> float:
        """``sqrt(1 + p / n)``: a new measurement's expected RMS error over the noise floor (poses like the
        fit's; the parameters' uncertainty adds to the noise, docs/kinematic_calibration.md)."""
        if not self.n_parameters or not self.n_residuals:
            return 1.0
        return float(np.sqrt(1.0 + self.n_parameters / self.n_residuals))


def load_stored_model(model: str | Path) -> StoredModel:
    """Any model vgr writes: an augmented model of ``vgr gap`` (``augmented_model.yaml``, ``model_<k>_*.yaml``,
    ``model_0_baseline.yaml``), the result of ``vgr calibrate kinematics`` (``--json OUT`` or a report's
    ``result.json``: its ``estimate.model_file``), a robot model file, or a shipped robot name (frames as
    they are). Raises ValueError naming what the file is not."""
    path = Path(str(model))
    if path.suffix.lower() == ".json" and path.is_file():
        doc = read_document(path, "json")
        est = doc.get("estimate") if isinstance(doc, dict) else None
        if not isinstance(est, dict) or doc.get("kind") != "kinematic" or "model_file" not in est:
            raise ValueError(f"{path} is not a kinematic calibration result (vgr calibrate kinematics --json)")
        metrics = doc.get("metrics") or {}
        p = int(metrics.get("n_params_identified", 0)) or None
        dof = metrics.get("chi2_dof")
        sigma = metrics.get("sigma_position_mm")
        return StoredModel(
            robot_model_from_dict(est["model_file"], source=str(path)),
            [],
            "kinematic calibration",
            str(path),
            None if sigma is None else float(sigma) / 1e3,
            est.get("tool_point_offsets"),
            p,
            None if (dof is None or p is None) else int(dof) + p,
        )
    robot, effects = load_gap_model(model)
    if path.suffix in (".yaml", ".yml") and path.is_file() and effects is not None:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        if isinstance(doc, dict) and "vgr_gap_model" in doc:
            fit = doc.get("fit") or {}
            sigma = doc.get("noise_sigma_m")
            return StoredModel(robot, effects, "gap model", str(path), None if sigma is None else float(sigma),
                               doc.get("tool_points"), fit.get("n_parameters"), fit.get("n_residuals"))  # fmt: skip
    return StoredModel(robot, [], "robot model", str(model))
