"""Each real adapter offers exactly its device contract, as its simulated twin does; no SDK at import.

Every device also publishes its frames (``frames``, FrameTransforms) for the 3D view: the robot
contract has the port; cameras and trackers add it to theirs (see test_frame_tree.py).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from recipe_helpers import graph_from

from engine.messages import FrameTransforms
from engine.plugin_manager import load_registry
from plugins.devices.stages.file_camera import FileCamera
from plugins.devices.stages.realsense_camera import RealSenseCamera
from plugins.devices.stages.ur_robot import URRobot
from plugins.devices.stages.vive_tracker import ViveTracker
from plugins.interfaces import (
    CAMERA_OUTPUTS,
    CAMERA_SERVICES,
    ROBOT_OUTPUTS,
    ROBOT_SERVICES,
    TRACKER_OUTPUTS,
    TRACKER_SERVICES,
)
from plugins.sim.stages.camera import SimCamera
from plugins.sim.stages.robot import SimRobot
from plugins.sim.stages.tracker import SimTracker

PAIRS = [
    (URRobot, SimRobot, ROBOT_SERVICES, ROBOT_OUTPUTS, "device"),
    (ViveTracker, SimTracker, TRACKER_SERVICES, TRACKER_OUTPUTS, "sensor"),
    (RealSenseCamera, SimCamera, CAMERA_SERVICES, CAMERA_OUTPUTS, "sensor"),
    (FileCamera, SimCamera, CAMERA_SERVICES, CAMERA_OUTPUTS, "sensor"),
]


@pytest.mark.parametrize(
    ("adapter", "twin", "services", "outputs", "role"), PAIRS, ids=lambda x: getattr(x, "type_name", "")
)
def test_adapter_offers_exactly_the_contract_and_the_twin_offers_it_too(adapter, twin, services, outputs, role):
    assert dict(adapter.services) == dict(services)
    assert dict(adapter.outputs) == {**outputs, "frames": FrameTransforms}
    assert adapter.role == twin.role == role
    assert adapter.inputs == {} and adapter.uses == {}  # a device needs nothing from the recipe
    for name, spec in services.items():
        assert twin.services[name] == spec
    for name, msg in {**outputs, "frames": FrameTransforms}.items():
        assert twin.outputs[name] is msg


def test_adapters_are_registered_and_describable_without_any_sdk():
    code = textwrap.dedent(
        """
        import sys
        for m in ("rtde_receive", "rtde_control", "openvr", "pyrealsense2"):
            sys.modules[m] = None  # importing any of them now fails
        from engine.plugin_manager import load_registry
        reg = load_registry()
        for t in ("ur_robot", "vive_tracker", "realsense_camera", "file_camera"):
            d = reg.stages[t].describe()
            assert all(p["description"] for p in d["params"].values()), t
        print("ok")
        """
    )
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=root, env={"PYTHONPATH": str(root)}
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_sim_capture_recipe_validates_with_the_real_devices_swapped_in():
    text = Path(__file__).resolve().parents[2].joinpath("recipes/sim_capture.yaml").read_text()
    text = text.replace(
        "type: sim_robot\n    params: {model: ur5e}",
        "type: ur_robot\n    params: {ip: 10.0.0.2, workspace_min_m: [-1, -1, 0], workspace_max_m: [1, 1, 1]}",
    )
    start = text.index("  camera:\n")
    end = text.index("  start:\n")
    text = text[:start] + "  camera:\n    type: file_camera\n    params: {folder: /tmp}\n" + text[end:]
    graph = graph_from(text)
    assert graph.nodes["robot"].cls is URRobot and graph.nodes["camera"].cls is FileCamera
    assert load_registry().stages["realsense_camera"] is RealSenseCamera
