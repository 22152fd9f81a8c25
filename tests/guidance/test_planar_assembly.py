"""Seed 004 on the simulated cell: recipes/planar_assembly.yaml and its absolute-pose baseline.

The recipe must be consistent with its cell (the taught install pose is what the controller of the
DH-error robot reports with the master plate seated; the teach recipe saw the same cell), must
assemble (every pin within the 0.5 mm radial clearance, truth) and replay bit for bit; the baseline
of benchmarks/guidance.py must reduce to the truth when the calibrations it relies on are exact.
"""

from __future__ import annotations

from pathlib import Path

import guidance_trials as gt
import numpy as np
import pytest
import yaml

from engine.graph import build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe
from engine.recording.diff import DIFFERENT
from engine.recording.recorder import Recorder
from engine.recording.replay import replay
from engine.run.runner import Runner
from engine.transforms import T_from_rotvec, pose_error
from plugins.params import PoseSpec
from plugins.robot.effects import effects_from_config
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects
from plugins.util.workpieces import assembled_plate_pose

RECIPES = Path(__file__).resolve().parents[2] / "recipes"
pytestmark = pytest.mark.timeout(600)


def _recipe(name: str) -> dict:
    return yaml.safe_load((RECIPES / name).read_text())


def _robot(data: dict) -> RobotWithEffects:
    p = data["stages"]["robot"]["params"]
    return RobotWithEffects(load_robot_model(p["model"]), effects_from_config(p.get("effects")))


def test_joints_reaching_puts_the_true_tcp_on_the_target() -> None:
    robot = _robot(_recipe("planar_assembly.yaml"))
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = T_from_rotvec(rng.normal(size=3) * 0.3 + (np.pi, 0, 0), (-0.45, 0.1, 0.2) + rng.normal(size=3) * 0.05)
        q = robot.joints_reaching(T)
        t, r = pose_error(robot.fk(q), T)
        assert t < 1e-9 and r < 1e-9
        t_nominal, _ = pose_error(robot.nominal.fk(q), T)
        assert t_nominal > 1e-5  # the robot's errors are real: the nominal model is elsewhere


def test_taught_install_pose_is_what_the_controller_reports_with_the_master_seated() -> None:
    data = _recipe("planar_assembly.yaml")
    robot = _robot(data)
    base = next(p for p in data["stages"]["camera"]["params"]["parts"] if p["name"] == "base_plate")
    T_true = PoseSpec.model_validate(base["pose"]).T() @ assembled_plate_pose()  # nominal grasp: TCP = plate frame
    reported = robot.nominal.fk(robot.joints_reaching(T_true))
    t, r = pose_error(PoseSpec.model_validate(data["vars"]["install_pose"]).T(), reported)
    assert t < 1e-8 and r < 1e-8


def test_the_template_was_taught_on_the_same_cell() -> None:
    run, teach = _recipe("planar_assembly.yaml"), _recipe("teach/planar_assembly_teach.yaml")
    assert run["stages"]["robot"]["params"]["effects"] == teach["stages"]["robot"]["params"]["effects"]
    assert run["stages"]["camera"]["params"]["mount"] == teach["stages"]["camera"]["params"]["mount"]
    photo_run = PoseSpec.model_validate(run["vars"]["photo_pose"]).T()
    photo_teach = PoseSpec.model_validate(teach["stages"]["capture"]["params"]["photo_pose"]).T()
    np.testing.assert_allclose(photo_run, photo_teach, atol=1e-12)


def test_the_shipped_recipe_assembles_and_replays_bit_for_bit(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    loaded = load_recipe(str(RECIPES / "planar_assembly.yaml"))
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    summary = Runner(graph, observers=[Recorder(path, graph.recipe.record, graph.loaded, ["builtin"])]).run()
    assert summary.ok, summary.stop_reason
    assert [e for e in summary.events if e.level == "alarm"] == []
    (ev,) = [e.details for e in summary.events if e.level == "result" and e.code == "docking_evaluation"]
    assert ev["success"] and max(ev["pin_offsets_mm"]) < 0.5, ev
    report, _, _ = replay(path)
    bad = [f"{v.topic}: {v.first_difference}" for v in (*report.streams, *report.requests) if v.verdict == DIFFERENT]
    assert not bad and not report.failures, "\n".join(bad + report.failures)


def test_relative_control_assembles_where_the_absolute_baseline_cannot() -> None:
    """One random draw: vgr's iterative relative control puts both pins in their holes; the absolute
    baseline with the issue's hand-eye error (1 mm / 0.5 deg) misses by millimetres, and with an exact
    hand-eye its error is the robot's absolute-accuracy difference only (well under 1 mm)."""
    trial = gt.run_trial("planar_assembly", 31)
    assert trial.converged and trial.evaluation["success"], trial.evaluation
    wrong = gt.absolute_assembly(trial)["absolute"]
    exact = gt.absolute_assembly(trial, hand_eye_scale=0.0)["absolute"]
    assert not wrong["success"] and wrong["error_mm"] > 1.0
    assert exact["error_mm"] < 1.0 and exact["error_mm"] < wrong["error_mm"] / 3


@pytest.mark.parametrize("seed", [1104, 1123])
def test_a_first_look_whose_best_candidates_are_refuted_still_finds_the_plate(seed: int) -> None:
    """Draws with the grasp turned ~9 deg where the global registration's first fine candidates all
    failed the contour check (the look was refused, nothing moved): the next coarse candidate is
    refined too, so the first look is usable and the plate is assembled."""
    trial = gt.run_trial("planar_assembly", seed)
    g = trial.guidance["guidance"]
    assert g.match_verdicts[0] == "ok", g.reasons
    assert trial.converged and trial.evaluation["success"], (g.reasons, trial.evaluation)
