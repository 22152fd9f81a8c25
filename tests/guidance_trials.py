"""Randomised trials of the shipped guidance recipes on the simulated cell (a Monte Carlo of the guidance scenarios).

One trial = one run of a shipped recipe (``recipes/*_dock.yaml``, ``recipes/planar_assembly.yaml``)
through the real engine with, drawn from the trial's seed:

* the part placement (eye-in-hand target) and/or the grasp (eye-to-hand held part) off by a uniform
  in-plane offset: x, y in +-``offset_mm`` and a turn about the part's normal in +-``offset_deg``;
* every camera pose that guidance believes (``hand_eye``) off the true mount by exactly
  ``hand_eye_mm`` in a random direction and ``hand_eye_deg`` about a random axis;
* the recipe's seed (so the camera noise differs per trial).

The result of a trial is read from the engine: each guidance stage's ``GuidanceResult`` (verdict,
moves, each look's ``T_match``) and the ``docking_evaluator``'s truth (docking error, or for the
planar assembly the pins' offsets from the hole axes). :func:`absolute_assembly` turns the first look
of a planar-assembly trial into the paper's absolute-pose baseline (seed 004, table 1).
The benchmark (benchmarks/guidance.py) and the tests (tests/guidance/test_guidance_trials.py) use it; it is a
test and benchmark harness, not part of the simulated cell, so it lives with the tests.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from engine.graph import build_graph
from engine.messages import PointCloud, codec
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe
from engine.run.runner import Observer, Runner
from engine.run.stage_host import ServiceCall
from engine.transforms import T_from_Rt, inv
from plugins.actions import guidance_math as gm
from plugins.actions.messages import GuidanceResult
from plugins.params import PoseSpec
from plugins.registration.template import load_template
from plugins.robot.effects import effects_from_config
from plugins.robot.model_file import load_robot_model, transform_entry
from plugins.robot.with_effects import RobotWithEffects
from plugins.sim.sensor_effects import PoseOffset
from plugins.sim.stages.evaluation import assembly_fit
from plugins.util.workpieces import assembled_plate_pose

RECIPES = Path(__file__).resolve().parents[1] / "recipes"

#: scenario -> (recipe file, {guidance stage: camera stage whose mount it believes},
#:              {camera stage: [(part, what moves it)]}) where "what" is "placement" or "grasp".
SCENARIOS: dict[str, tuple[str, dict[str, str], dict[str, list[tuple[str, str]]]]] = {
    "eye_in_hand": ("eye_in_hand_dock.yaml", {"guidance": "camera"}, {"camera": [("part", "placement")]}),
    "eye_to_hand": ("eye_to_hand_dock.yaml", {"guidance": "camera"}, {"camera": [("held", "grasp")]}),
    "dual": (
        "dual_dock.yaml",
        {"target_guidance": "hand_camera", "held_guidance": "fixed_camera"},
        {"hand_camera": [("target", "placement")], "fixed_camera": [("target", "placement"), ("held", "grasp")]},
    ),
    "planar_assembly": ("planar_assembly.yaml", {"guidance": "camera"}, {"camera": [("plate", "grasp")]}),
}


@dataclass(frozen=True)
class TrialSpec:
    """The disturbances of the issue: +-20 mm / +-10 deg offsets, hand-eye off by 1 mm / 0.5 deg."""

    offset_mm: float = 20.0
    offset_deg: float = 10.0
    hand_eye_mm: float = 1.0
    hand_eye_deg: float = 0.5


@dataclass
class Trial:
    """What one run did and what the truth says about it."""

    scenario: str
    seed: int
    offsets: dict[str, PoseOffset]  # "placement" / "grasp" -> the drawn offset
    hand_eye_error: dict[str, np.ndarray]  # guidance stage -> (6,): position error (m), rotation vector (rad)
    ok: bool  # the run itself finished (no stage failure)
    stop_reason: str | None
    guidance: dict[str, GuidanceResult] = field(default_factory=dict)
    evaluation: dict[str, Any] = field(default_factory=dict)
    alarms: list[tuple[str, str]] = field(default_factory=list)
    recipe_data: dict[str, Any] = field(default_factory=dict)
    captures: list[PointCloud] = field(default_factory=list)  # camera replies, in order (keep_captures)

    @property
    def converged(self) -> bool:
        return bool(self.guidance) and all(g.converged for g in self.guidance.values())

    @property
    def moves(self) -> dict[str, int]:
        return {k: g.moves for k, g in self.guidance.items()}

    @property
    def docked(self) -> bool:
        return bool(self.evaluation.get("docked"))


class _GuidanceResults(Observer):
    """Keeps every GuidanceResult published in the run (by stage) and, if asked, every capture."""

    def __init__(self, keep_captures: bool) -> None:
        self.results: dict[str, GuidanceResult] = {}
        self.keep_captures = keep_captures
        self.captures: list[PointCloud] = []

    def on_publish(self, stage: str, port: str, payload: bytes, envelope: bytes, msg: Any) -> None:
        if isinstance(msg, GuidanceResult):
            self.results[stage] = msg

    def on_service(self, call: ServiceCall) -> None:
        if self.keep_captures and call.edge.service == "capture" and not call.error:
            cloud = codec.decode(call.reply_payload, codec.decode_envelope(call.reply_env))
            if isinstance(cloud, PointCloud):
                self.captures.append(cloud)


def _offset(rng: np.random.Generator, spec: TrialSpec) -> PoseOffset:
    x, y = rng.uniform(-spec.offset_mm, spec.offset_mm, 2) / 1e3
    turn = np.radians(rng.uniform(-spec.offset_deg, spec.offset_deg))
    return PoseOffset((float(x), float(y), 0.0), (0.0, 0.0, float(turn)))


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def perturbed_pose(T_true: np.ndarray, dt_m: np.ndarray, drot_rad: np.ndarray) -> np.ndarray:
    """A believed pose: position off by ``dt_m``, orientation turned by ``drot_rad`` (rotation vector)."""
    return T_from_Rt(Rotation.from_rotvec(drot_rad).as_matrix() @ T_true[:3, :3], T_true[:3, 3] + dt_m)


def _offset_dict(o: PoseOffset) -> dict[str, list[float]]:
    return {
        "translation_m": [float(v) for v in o.translation_m],
        "rotation_deg": [float(v) for v in np.degrees(o.rotation_rotvec_rad)],
    }


def recipe_data(scenario: str) -> dict[str, Any]:
    """The shipped recipe of a scenario as plain data (YAML anchors expanded into copies)."""
    recipe, _, _ = SCENARIOS[scenario]
    return copy.deepcopy(yaml.safe_load((RECIPES / recipe).read_text()))


def mount_pose(data: dict[str, Any], camera: str) -> np.ndarray:
    """The true mount of a camera stage of the recipe (T_tcp_cam in hand, T_world_cam fixed)."""
    return PoseSpec.model_validate(data["stages"][camera]["params"]["mount"]["pose"]).T()


def draw(
    scenario: str, seed: int, spec: TrialSpec = TrialSpec(), extra: dict[str, Any] | None = None
) -> tuple[dict[str, Any], dict[str, PoseOffset], dict[str, np.ndarray]]:
    """The recipe data of one trial: offsets and hand-eye errors drawn from ``seed`` (see module doc).

    ``extra`` maps ``stage.param`` to a value set in the recipe too (e.g. ``matcher.global_method``,
    ``camera.intrinsics``).
    Returns ``(data, offsets, hand-eye errors by guidance stage as (6,) [dt_m, drot_rad])``.
    """
    _, believers, moved = SCENARIOS[scenario]
    rng = np.random.default_rng(seed)
    data = recipe_data(scenario)
    data["seed"] = int(seed)
    offsets = {"placement": _offset(rng, spec), "grasp": _offset(rng, spec)}
    for camera, parts in moved.items():
        placement = data["stages"][camera]["params"].setdefault("effects", {}).setdefault("placement", {})
        for part, what in parts:
            placement[part] = _offset_dict(offsets[what])
    errors = {}
    for guidance, camera in believers.items():
        dt = _unit(rng) * spec.hand_eye_mm / 1e3
        drot = _unit(rng) * np.radians(spec.hand_eye_deg)
        errors[guidance] = np.concatenate([dt, drot])
        believed = perturbed_pose(mount_pose(data, camera), dt, drot)
        data["stages"][guidance]["params"]["hand_eye"] = transform_entry(believed)
    for key, value in (extra or {}).items():
        stage, param = key.split(".", 1)
        data["stages"][stage].setdefault("params", {})[param] = value
    used = {k: v for k, v in offsets.items() if any(w == k for parts in moved.values() for _, w in parts)}
    return data, used, errors


def run_trial(
    scenario: str,
    seed: int,
    spec: TrialSpec = TrialSpec(),
    *,
    extra: dict[str, Any] | None = None,
    keep_reports: bool = False,
    keep_captures: bool = False,
) -> Trial:
    """Run one randomised trial of a scenario through the engine (no recording)."""
    recipe, _, _ = SCENARIOS[scenario]
    data, offsets, errors = draw(scenario, seed, spec, extra)
    if not keep_reports:  # the report sinks draw PNGs: seconds per run that a Monte Carlo does not need
        data["stages"] = {k: v for k, v in data["stages"].items() if v.get("type") != "guidance_report"}
    loaded = load_recipe(str(RECIPES / recipe), [], text=yaml.safe_dump(data, sort_keys=False))
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    seen = _GuidanceResults(keep_captures)
    summary = Runner(graph, observers=[seen]).run()
    evaluation = next((e.details for e in summary.events if e.level == "result" and e.code == "docking_evaluation"), {})
    return Trial(
        scenario=scenario,
        seed=seed,
        offsets=offsets,
        hand_eye_error=errors,
        ok=summary.ok,
        stop_reason=summary.stop_reason,
        guidance=seen.results,
        evaluation=dict(evaluation),
        alarms=[(e.stage, e.code) for e in summary.events if e.level == "alarm"],
        recipe_data=data,
        captures=seen.captures,
    )


# -- seed 004's absolute-pose baseline ----------------------------------------------------------------


def _true_robot(data: dict[str, Any]) -> RobotWithEffects:
    p = data["stages"]["robot"]["params"]
    return RobotWithEffects(load_robot_model(p.get("model", "ur5e")), effects_from_config(p.get("effects")))


def _part(data: dict[str, Any], name: str) -> dict[str, Any]:
    return next(p for p in data["stages"]["camera"]["params"]["parts"] if p["name"] == name)


def _execute(robot: RobotWithEffects, T_cmd: np.ndarray, q_seed: np.ndarray) -> np.ndarray | None:
    """True TCP after the controller moves to ``T_cmd`` (nominal IK); None when it cannot."""
    ik = robot.nominal.ik(T_cmd, q_seed)
    return robot.fk(ik.q) if ik.success and ik.q is not None else None


def absolute_assembly(trial: Trial, hand_eye_scale: float = 1.0) -> dict[str, Any]:
    """The paper's baseline on a planar-assembly trial: absolute-pose control from the first look.

    The tool (grasp) frame is calibrated from that look, ``G = T_start^-1 C' T_cam_part``, where
    ``T_cam_part = T_match^-1 T_cam_template`` is what registering the capture against the CAD model
    gives (the template's true pose in the camera) and ``C'`` is the believed camera pose with the
    trial's hand-eye error times ``hand_eye_scale``; the robot is commanded to ``T_slot G^-1`` with the
    slot's pose known exactly (the most favourable case for the baseline). Executed by the robot's
    nominal inverse kinematics on the true (DH-error) robot; judged by :func:`assembly_fit`.
    Also returns the one-look relative variant (the paper's relative-pose control: one step
    ``C' T_match C'^-1 T_start``, then docking) under ``relative_one_look``.
    """
    g = trial.guidance.get("guidance")
    if g is None or not g.matches:
        return {"absolute": {"success": False, "reason": "no usable first look"}, "relative_one_look": None}
    data = trial.recipe_data
    robot = _true_robot(data)
    camera_params = data["stages"]["camera"]["params"]
    C_true = mount_pose(data, "camera")
    dt, drot = trial.hand_eye_error["guidance"][:3], trial.hand_eye_error["guidance"][3:]
    C_believed = perturbed_pose(C_true, dt * hand_eye_scale, drot * hand_eye_scale)
    G_nominal = PoseSpec.model_validate(_part(data, "plate").get("pose", {})).T()
    G_true = PoseOffset.from_dict(camera_params["effects"]["placement"]["plate"]).apply(G_nominal)
    T_world_base = PoseSpec.model_validate(_part(data, "base_plate")["pose"]).T()
    guidance = data["stages"]["guidance"]["params"]

    # the template: the master plate at the teach photo pose, seen by the true camera
    template = load_template(RECIPES / data["stages"]["matcher"]["params"]["template"])
    q_teach = robot.nominal.ik(template.T_base_tcp_photo).q
    T_cam_template = inv(C_true) @ robot.fk(q_teach) @ G_nominal

    T_match = g.matches[0]
    T_cam_part = inv(T_match) @ T_cam_template
    G_measured = inv(g.T_start) @ C_believed @ T_cam_part
    T_slot = T_world_base @ assembled_plate_pose()
    q_photo = robot.nominal.ik(g.T_start).q
    out: dict[str, Any] = {}
    tcp = _execute(robot, T_slot @ inv(G_measured), q_photo)
    out["absolute"] = (
        {"success": False, "reason": "unreachable"} if tcp is None else assembly_fit(tcp @ G_true, T_world_base)
    )
    # the paper's relative-pose control: one look, one step, then the docking formula
    C_guidance = PoseSpec.model_validate(guidance["hand_eye"]).T()
    T_end = gm.delta_eye_to_hand(T_match, C_guidance) @ g.T_start
    T_install = PoseSpec.model_validate(data["vars"]["install_pose"]).T()
    tcp = _execute(robot, gm.dock_eye_to_hand(g.T_start, T_end, T_install), q_photo)
    out["relative_one_look"] = (
        {"success": False, "reason": "unreachable"} if tcp is None else assembly_fit(tcp @ G_true, T_world_base)
    )
    return out
