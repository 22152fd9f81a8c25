"""Recipe pieces the adapter run tests share: the header of a run with the adapter test stages, the
UR robot at the fake controller, and triggered captures at a photo pose.

Each piece is finished YAML text (no ``str.format`` left to do): join them with
``recipe_helpers.stages()``.
"""

from __future__ import annotations

from fake_ur_rtde import IP, WORKSPACE
from recipe_helpers import header

SIM_PHOTO = "[[0, 1, 0, -0.49], [1, 0, 0, -0.14], [0, 0, -1, 0.45], [0, 0, 0, 1]]"  # a pose the sim UR5e reaches


def adapter_header(name: str, run_id: str | None = None) -> str:
    """The top of a recipe on the simulated clock with the adapter test stages (adapter_fixtures) loaded."""
    return header(name, plugins=["adapter_fixtures"], run_id=run_id, clock="sim")


def ur_robot(params: str = WORKSPACE) -> str:
    """The ``robot`` stage: ur_robot at the fake controller's address; *params*, its other parameters
    (YAML mapping entries), by default the workspace box."""
    return f"robot: {{type: ur_robot, params: {{ip: {IP}, {params}}}}}"


def capture_at_pose(photo: str, count: int) -> str:
    """``start`` (*count* triggers) and ``capture``: capture_at_pose with ``robot`` and ``camera`` at
    *photo* (a YAML matrix)."""
    return f"""
    start: {{type: trigger, params: {{count: {count}}}}}
    capture:
      type: capture_at_pose
      inputs: {{trigger: start.out}}
      uses: {{robot: robot.move, camera: camera.capture}}
      params: {{photo_pose: {{matrix: {photo}}}}}
    """
