"""Helpers for the calibration-stage tests: run a recipe in-process (optionally recorded), collect
what every stage published, and the ground truth of the simulated calibration recipes."""

from __future__ import annotations

import json
import textwrap
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from shared_data import SHARED

from engine.graph import build_graph
from engine.messages import codec
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe
from engine.recording.recorder import Recorder
from engine.run.runner import Observer, Runner, RunSummary
from plugins.calibration.result import CalibrationResult

ROOT = Path(__file__).resolve().parents[2]
RECIPES = ROOT / "recipes"
MOVEIT = SHARED / "moveit_calibration" / "pose_samples.json"
MOVEIT_T_BASE_CAM_M = np.array([0.659, -0.249, 0.830])  # MoveIt's asserted answer (1 % tolerance)


class Keep(Observer):
    """Every published message by (stage, port) and every service request by (stage, "_svc/" client),
    in order."""

    def __init__(self) -> None:
        self.msgs: dict[tuple[str, str], list[Any]] = defaultdict(list)

    def on_publish(self, stage, port, payload, envelope, msg):
        self.msgs[(stage, port)].append(msg)

    def on_service(self, call):
        self.msgs[(call.stage, f"_svc/{call.client}")].append(
            codec.decode(call.req_payload, codec.decode_envelope(call.req_env))
        )


def run(
    recipe: str | Path | None = None,
    overrides: list[str] | None = None,
    *,
    text: str | None = None,
    record: Path | None = None,
    run_dir: Path | None = None,
) -> tuple[RunSummary, dict[tuple[str, str], list[Any]]]:
    """Run a recipe file (or recipe *text*) in this process (its files in *run_dir*, as ``vgr run``'s
    run folder); returns the summary and the messages."""
    source = str(recipe) if recipe is not None else "test.yaml"
    loaded = load_recipe(source, overrides, text=None if text is None else textwrap.dedent(text))
    registry = load_registry(loaded.recipe.plugins)
    graph = build_graph(loaded, registry)
    keep = Keep()
    observers: list[Observer] = [keep]
    if record is not None:
        observers.append(Recorder(record, graph.recipe.record, graph.loaded, registry.plugins))
    runner = Runner(graph, observers=observers)
    runner.run_dir = run_dir
    summary = runner.run()
    return summary, keep.msgs


def results(msgs, stage: str = "calibrate") -> list[CalibrationResult]:
    return [CalibrationResult.from_dict(json.loads(m.result_json)) for m in msgs[(stage, "result")]]


def events(summary: RunSummary, code: str) -> list[Any]:
    return [e for e in summary.events if e.code == code]


def mahalanobis2(err: np.ndarray, cov: np.ndarray) -> float:
    return float(err @ np.linalg.solve(cov, err))
