"""The shipped guidance recipes, end to end on the simulated cell, judged against simulation truth.

Each scenario runs through the real engine (zenoh, services, recorder), must converge and dock within the issue's bounds (truth, from the docking evaluator),
and its recording must replay bit for bit. Safety through the whole engine: an out-of-limit step
and an empty view end with a recorded alarm and no corrective or docking move.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.graph import build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe
from engine.recording.diff import DIFFERENT
from engine.recording.reader import load
from engine.recording.recorder import Recorder
from engine.recording.replay import replay
from engine.run.runner import Runner, RunSummary

RECIPES = Path(__file__).resolve().parents[2] / "recipes"
SMALL = ["camera.intrinsics.width=320", "camera.intrinsics.height=240"]
pytestmark = pytest.mark.timeout(300)


def run(recipe: str, overrides: list[str], record: Path | None = None) -> RunSummary:
    loaded = load_recipe(str(RECIPES / recipe), overrides)
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    observers = [Recorder(record, graph.recipe.record, graph.loaded, ["builtin"])] if record else []
    summary = Runner(graph, observers=observers).run()
    assert summary.ok, summary.stop_reason
    return summary


def results(summary: RunSummary, code: str) -> list[dict]:
    return [e.details for e in summary.events if e.level == "result" and e.code == code]


def moves(path: Path, caller: str) -> list[str]:
    """Request types *caller* sent to the robot's move service, from the recording."""
    return [
        r[1].request_type
        for r in load(path).records
        if r[0] == "svc" and r[1].caller == caller and r[1].provider == "robot" and r[1].service == "move"
    ]


def alarms(summary: RunSummary) -> list[tuple[str, str]]:
    return [(e.stage, e.code) for e in summary.events if e.level == "alarm"]


# (max docking error mm, deg) from the issue. Full camera resolution: at 320 x 240 the matcher's
# rotation noise (~0.012 deg per look) is above the default 0.01 deg tolerance and guidance cannot
# prove convergence (measured: dual_dock stops not_converged after 5 moves at 0.018 deg).
SCENARIOS = {"eye_in_hand_dock.yaml": (0.1, 0.05), "eye_to_hand_dock.yaml": (0.1, 0.05), "dual_dock.yaml": (0.2, 0.1)}


@pytest.mark.parametrize("recipe", sorted(SCENARIOS))
def test_scenario_docks_within_bounds_and_replays_bit_for_bit(recipe: str, tmp_path: Path) -> None:
    max_mm, max_deg = SCENARIOS[recipe]
    path = tmp_path / "run.mcap"
    summary = run(recipe, [], record=path)
    assert alarms(summary) == []
    reports = results(summary, "guidance_report")
    assert reports and all(r["job"] == 1 for r in reports)
    (truth,) = results(summary, "docking_evaluation")
    assert truth["docked"] and truth["error_mm"] < max_mm and truth["error_deg"] < max_deg, truth

    report, _, _ = replay(path)
    bad = [f"{v.topic}: {v.first_difference}" for v in (*report.streams, *report.requests) if v.verdict != "identical"]
    assert not bad and not report.failures, "\n".join(bad + report.failures)


def test_step_over_the_limit_moves_nothing_and_records_the_alarm(tmp_path: Path) -> None:
    path = tmp_path / "limit.mcap"
    summary = run("eye_in_hand_dock.yaml", [*SMALL, "guidance.max_step_mm=5"], record=path)
    assert ("guidance", "correction_limit") in alarms(summary)
    assert ("docking", "guidance_not_usable") in alarms(summary)
    assert len(moves(path, "guidance")) == 1, "only the move to the photo pose"
    assert moves(path, "docking") == []
    recorded = [m.payload for m in load(path).messages("/guidance/events")]
    assert any(b"correction_limit" in p for p in recorded)
    (truth,) = results(summary, "docking_evaluation")
    assert not truth["docked"]


def test_empty_view_moves_nothing_and_raises_an_alarm(tmp_path: Path) -> None:
    far = "camera.effects={placement: {part: {translation_m: [0.35, 0, 0]}}}"
    summary = run("eye_in_hand_dock.yaml", [*SMALL, far], record=tmp_path / "empty.mcap")
    assert ("guidance", "match_failed") in alarms(summary)
    assert len(moves(tmp_path / "empty.mcap", "guidance")) == 1 and moves(tmp_path / "empty.mcap", "docking") == []
    (truth,) = results(summary, "docking_evaluation")
    assert not truth["docked"] and "match failed" in truth["reason"]


def test_golden_recordings_of_the_scenarios_exist() -> None:
    golden = Path(__file__).resolve().parents[2] / "recordings"
    for name in ("eye_in_hand_dock", "eye_to_hand_dock", "dual_dock"):
        assert (golden / f"{name}.mcap").is_file(), f"make golden records recordings/{name}.mcap"


def test_replay_reports_a_changed_guidance_tolerance(tmp_path: Path) -> None:
    """The replay is a regression test: a looser tolerance stops the loop earlier, and replay says so."""
    path = tmp_path / "run.mcap"
    run("eye_in_hand_dock.yaml", [], record=path)
    report, _, _ = replay(path, overrides=["guidance.translation_tol_mm=1.0", "guidance.rotation_tol_deg=0.1"])
    assert any(v.verdict == DIFFERENT for v in (*report.streams, *report.requests))
