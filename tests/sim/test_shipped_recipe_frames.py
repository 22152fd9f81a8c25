"""Every shipped recipe, run on the simulated cell and recorded, draws one frame tree and its captures.

Each recipe under recipes/ (the teach recipes too) runs once, recorded (shipped_runs: the long
campaigns with fewer poses); a recipe with a hardware device is skipped. In the recording:

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
from frame_tree_helpers import frame_tree
from shipped_runs import SHIPPED, recipe_id, shipped_run

from engine.messages import PointCloud, codec
from engine.recording.reader import load
from plugins.calibration.stages.base import CalibrationStage

pytestmark = pytest.mark.timeout(180)


@pytest.mark.parametrize("recipe", SHIPPED, ids=recipe_id)
def test_a_shipped_recipe_records_one_frame_tree_under_world_and_draws_its_captures(recipe: Path) -> None:
    run = shipped_run(recipe)
    if run.path is None:
        pytest.skip(f"needs hardware: {', '.join(run.hardware)}")

    tree = frame_tree(run.path)
    assert not tree.problems(), "\n".join(tree.problems())

    rec = load(run.path)
    topics = {m.topic for m in rec.messages()}
    for name, node in run.graph.nodes.items():
        if issubclass(node.cls, CalibrationStage):
            assert f"/{name}/transform" in topics, f"{name}: no transform published (calibration not usable?)"

    cameras = {getattr(n.params, "frame_id", "camera") for n in run.graph.nodes.values() if "capture" in n.cls.services}
    drawn: set[str] = set()
    for m in rec.messages():
        cloud = codec.decode_payload(PointCloud, m.payload) if m.type_name == PointCloud.TYPE else None
        if isinstance(cloud, PointCloud) and len(cloud.points):
            drawn.add(cloud.frame_id)
    assert cameras <= drawn, f"captures of {sorted(cameras - drawn)} are on no PointCloud channel"
