"""docs/foxglove/vgr_layout.json, the Foxglove layout for the shipped recipes' recordings.

The layout is a Foxglove Studio layout (``configById`` panels, a ``layout`` tree of panel ids, Tab
panels holding their own layouts). Its 3D panel follows ``world`` and shows the point clouds, scene
meshes and poses (transforms are read from every topic by Foxglove itself); Raw Messages panels
show the events of the main stages. Checked against a recorded run of each shipped recipe
(shipped_runs, the demo recipe among them): every topic the layout names is recorded by a shipped
recipe, and every cloud, mesh and pose topic a shipped recipe records is shown, as is one of its
events topics when it has any.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from shipped_runs import SHIPPED, recipe_id, shipped_run

from engine.messages import PointCloud, PoseStamped, SceneMeshes
from engine.recording.reader import load

pytestmark = pytest.mark.timeout(180)

LAYOUT = Path(__file__).resolve().parents[1] / "docs" / "foxglove" / "vgr_layout.json"
DRAWN = {PointCloud.TYPE, SceneMeshes.TYPE, PoseStamped.TYPE}  # what the 3D panel draws from a topic


def _layout() -> dict[str, Any]:
    return json.loads(LAYOUT.read_text(encoding="utf-8"))


def _panel_ids(node: Any, config: dict[str, Any]) -> list[str]:
    """Panel ids of a layout tree (a panel id, or ``first``/``second`` splits), Tab panels' tabs included."""
    if isinstance(node, str):
        tabs = config.get(node, {}).get("tabs", []) if node.startswith("Tab!") else []
        return [node] + [i for tab in tabs for i in _panel_ids(tab["layout"], config)]
    return _panel_ids(node["first"], config) + _panel_ids(node["second"], config)


def _panels(kind: str) -> list[dict[str, Any]]:
    layout = _layout()
    config = layout["configById"]
    return [config[i] for i in _panel_ids(layout["layout"], config) if i.split("!")[0] == kind]


def _scene_topics() -> dict[str, dict[str, Any]]:
    (scene,) = _panels("3D")
    return scene["topics"]


def _events_topics() -> set[str]:
    return {p["topicPath"] for p in _panels("RawMessages")}


def _recorded(recipe: Path) -> dict[str, str]:
    """topic -> message type of the recipe's recorded run."""
    run = shipped_run(recipe)
    if run.path is None:
        pytest.skip(f"needs hardware: {', '.join(run.hardware)}")
    return {m.topic: m.type_name for m in load(run.path).messages()}


def test_the_layout_is_a_foxglove_layout_whose_3d_panel_follows_world():
    layout = _layout()
    config = layout["configById"]
    shown = _panel_ids(layout["layout"], config)
    assert sorted(shown) == sorted(config), "every panel configured is placed in the layout, and only those"
    (scene,) = _panels("3D")
    assert scene["followTf"] == "world" and scene["followMode"] in ("follow-pose", "follow-position")
    assert scene["topics"] and all(t["visible"] for t in scene["topics"].values())
    assert _events_topics() and all(t.endswith("/events") for t in _events_topics())


def test_every_topic_the_layout_names_is_recorded_by_a_shipped_recipe():
    recorded: dict[str, set[str]] = {}
    for recipe in SHIPPED:
        run = shipped_run(recipe)
        if run.path is not None:
            for m in load(run.path).messages():
                recorded.setdefault(m.topic, set()).add(m.type_name)
    unknown = sorted(t for t in [*_scene_topics(), *_events_topics()] if t not in recorded)
    assert not unknown, f"the layout names topics no shipped recipe records: {unknown}"
    assert all(recorded[t] <= DRAWN for t in _scene_topics()), "a 3D topic carries something the panel cannot draw"


@pytest.mark.parametrize("recipe", SHIPPED, ids=recipe_id)
def test_the_layout_shows_what_a_recorded_run_of_a_shipped_recipe_draws(recipe: Path):
    """The demo recipe's run among them: its clouds, meshes and poses in the 3D panel, and an
    events topic of it in an events panel."""
    topics = _recorded(recipe)
    drawn = {t for t, kind in topics.items() if kind in DRAWN}
    missing = sorted(drawn - set(_scene_topics()))
    assert not missing, f"{recipe_id(recipe)} records topics the layout's 3D panel does not show: {missing}"
    events = {t for t in topics if t.endswith("/events")}
    assert not events or events & _events_topics(), f"no events panel reads any of {sorted(events)}"
