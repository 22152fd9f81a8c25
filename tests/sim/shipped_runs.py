"""The shipped recipes run on the simulated cell, recorded once per test session.

Which recipes there are (every ``recipes/**/*.yaml``, the teach recipes too), the shorter runs of the
long campaigns (fewer poses and fewer robot states along a move: their stages publish the same
frames and topics), which ones need hardware, and :func:`shipped_run`, which records a recipe on
first use into a temporary folder kept for the session, so the tests that read these recordings
(the frame tree, the Foxglove layout) share one run of each.
"""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from frame_tree_helpers import record_graph

from engine.graph import Graph, build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe

RECIPES = Path(__file__).resolve().parents[2] / "recipes"
# (a cell service's recipe runs as a service, not a run: tests/cell drive it, and its golden cycle file
# in recordings/ is checked for one frame tree with the other recordings)
SHIPPED = sorted(r for r in RECIPES.rglob("*.yaml") if "\nserve:" not in r.read_text(encoding="utf-8"))
HARDWARE = {"ur_robot", "realsense_camera", "vive_tracker"}  # device stages that need the real device
# fewer poses for the long campaigns (full length: ~45 s and ~35 s) and 2 robot states a second
# along a move instead of 25 (the robot's frames go out at set-up, along each move and at rest)
SHORTER = {
    "calibrate_kinematics_sim": ["vars.n_poses=30", "robot.state_rate_hz=2"],
    "model_gap_sim": ["campaign.n_poses=20", "robot.state_rate_hz=2"],
    "calibrate_handeye_sim": ["robot.state_rate_hz=2"],
}


@dataclass(frozen=True)
class ShippedRun:
    recipe: Path
    graph: Graph
    path: Path | None  # None: not run, it needs hardware
    hardware: tuple[str, ...] = ()


def recipe_id(path: Path) -> str:
    """``eye_in_hand_dock``, ``teach/eye_in_hand_teach``: a recipe's name under recipes/."""
    return str(path.relative_to(RECIPES).with_suffix(""))


@functools.cache
def _folder() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="vgr-shipped-runs-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


@functools.cache
def shipped_run(recipe: Path) -> ShippedRun:
    """*recipe* run recorded (once per session; the run must end well), or not run when it needs
    hardware."""
    loaded = load_recipe(recipe, SHORTER.get(recipe.stem, []))
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    hardware = tuple(sorted(n for n, node in graph.nodes.items() if node.cls.type_name in HARDWARE))
    if hardware:
        return ShippedRun(recipe, graph, None, hardware)
    path = _folder() / f"{recipe_id(recipe).replace('/', '-')}.mcap"
    record_graph(graph, path, ["builtin"])
    return ShippedRun(recipe, graph, path)
