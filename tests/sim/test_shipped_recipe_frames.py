"""Every shipped recipe, run on the simulated cell and recorded, draws one frame tree and its captures.

Each recipe under recipes/ (the teach recipes too) runs once, recorded to a temporary folder; the
long ones run with fewer poses (their stages publish the same frames). A recipe with a hardware
device is skipped. In the recording:

* every transform, on any port (``frames``, a calibration's ``transform``, ``truth/...``), forms one
  tree: each frame one parent, ``world`` at the root, every frame a message names connected to it
  (frame_tree_helpers: what a 3D view such as Foxglove draws);
* each calibration stage published its transforms (the calibration was usable, so its frames were
  checked, not skipped);
* each camera's captures are drawn: a PointCloud with points in the camera's frame (the dock
  recipes' captures travel in service exchanges, which a 3D view does not read).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from frame_tree_helpers import frame_tree, record_graph

from engine import codec
from engine.graph import build_graph
from engine.messages import PointCloud
from engine.plugin_manager import load_registry
from engine.recipe import load_recipe
from engine.recording import load
from plugins.solvers.stages.base import CalibrationStage

pytestmark = pytest.mark.timeout(180)

RECIPES = Path(__file__).resolve().parents[2] / "recipes"
SHIPPED = sorted(RECIPES.rglob("*.yaml"))
HARDWARE = {"ur_robot", "realsense_camera", "vive_tracker"}  # device stages that need the real device
# fewer poses for the long campaigns (full length: ~45 s and ~35 s) and 2 robot states a second
# along a move instead of 25 (the robot's frames go out at set-up, along each move and at rest)
SHORTER = {
    "calibrate_kinematics_sim": ["vars.n_poses=30", "robot.state_rate_hz=2"],
    "model_gap_sim": ["campaign.n_poses=20", "robot.state_rate_hz=2"],
    "calibrate_handeye_sim": ["robot.state_rate_hz=2"],
}


def _recipe_id(path: Path) -> str:
    return str(path.relative_to(RECIPES).with_suffix(""))


@pytest.mark.parametrize("recipe", SHIPPED, ids=_recipe_id)
def test_a_shipped_recipe_records_one_frame_tree_under_world_and_draws_its_captures(recipe, tmp_path):
    loaded = load_recipe(recipe, SHORTER.get(recipe.stem, []))
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    hardware = sorted(n for n, node in graph.nodes.items() if node.cls.type_name in HARDWARE)
    if hardware:
        pytest.skip(f"needs hardware: {', '.join(hardware)}")
    path = tmp_path / f"{recipe.stem}.mcap"
    record_graph(graph, path, ["builtin"])

    tree = frame_tree(path)
    assert not tree.problems(), "\n".join(tree.problems())

    rec = load(path)
    topics = {m.topic for m in rec.messages()}
    for name, node in graph.nodes.items():
        if issubclass(node.cls, CalibrationStage):
            assert f"/{name}/transform" in topics, f"{name}: no transform published (calibration not usable?)"

    cameras = {node.params.frame_id for node in graph.nodes.values() if "capture" in node.cls.services}
    drawn: dict[str, int] = {}
    for m in rec.messages():
        if m.type_name != PointCloud.TYPE:
            continue
        msg = codec.decode_payload(codec.registry.get(m.type_name), m.payload)
        if len(msg.points):
            drawn[msg.frame_id] = drawn.get(msg.frame_id, 0) + 1
    assert cameras <= set(drawn), f"captures of {sorted(cameras - set(drawn))} are on no PointCloud channel"
