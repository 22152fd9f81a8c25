"""The simulated cell as stages: a recorded capture run, truth kept from solvers, safe refusals."""

from __future__ import annotations

import numpy as np
import pytest
from recipe_helpers import graph_from, header, stages

from engine.errors import RecipeError
from engine.run.runner import Observer, Runner
from engine.transforms import inv, transform_points
from plugins.util.workpieces import make_workpiece

pytestmark = pytest.mark.timeout(120)

CELL = header("cell", seed=3, clock="sim") + stages("""
  robot: {{type: sim_robot, params: {{model: ur5e}}}}
  camera:
    type: sim_camera
    uses: {{robot: robot.truth}}
    params:
      noise: {{preset: noiseless}}
      mount: {{kind: eye_in_hand, pose: {{xyz_m: [0.0, 0.06, 0.03]}}}}
      parts: [{{name: part, workpiece: feature_part, pose: {{xyz_m: [-0.49, -0.08, 0.0], rpy_deg: [0, 0, 10]}}}}]
      effects: {effects}
  start: {{type: trigger, params: {{count: {count}}}}}
  capture:
    type: capture_at_pose
    inputs: {{trigger: start.out}}
    uses: {{robot: robot.move, camera: camera.capture}}
    params: {{photo_pose: {{matrix: [[0, 1, 0, {x}], [1, 0, 0, -0.14], [0, 0, -1, 0.45], [0, 0, 0, 1]]}}}}
""")


class Keep(Observer):
    def __init__(self) -> None:
        self.msgs: list[tuple[str, str, object]] = []

    def on_publish(self, stage, port, payload, envelope, msg):
        self.msgs.append((stage, port, msg))


def run_cell(effects: str = "{}", count: int = 1, x: float = -0.49):
    keep = Keep()
    summary = Runner(graph_from(CELL.format(effects=effects, count=count, x=x)), observers=[keep]).run()
    return summary, keep.msgs


def test_capture_sees_the_part_where_it_truly_is_and_time_passes():
    summary, msgs = run_cell()
    assert summary.ok, summary.stop_reason
    cloud = next(m for s, p, m in msgs if (s, p) == ("capture", "cloud"))
    pose = next(m for s, p, m in msgs if (s, p) == ("capture", "pose"))
    assert len(cloud.points) > 2000 and cloud.frame_id == "camera"
    T_tcp_cam = np.eye(4)
    T_tcp_cam[:3, 3] = (0.0, 0.06, 0.03)
    pts_world = transform_points(pose.T @ T_tcp_cam, cloud.points)
    part = make_workpiece("feature_part")
    T_world_part = np.eye(4)
    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    T_world_part[:2, :2] = [[c, -s], [s, c]]
    T_world_part[:3, 3] = (-0.49, -0.08, 0.0)
    local = transform_points(inv(T_world_part), pts_world)
    lo, hi = part.vertices().min(axis=0), part.vertices().max(axis=0)
    inside = np.all((local >= lo - 1e-4) & (local <= hi + 1e-4), axis=1)
    assert inside.mean() > 0.999  # every point lies on the part's bounding box (noiseless, no effects)
    robot_states = [m for s, p, m in msgs if (s, p) == ("robot", "tcp_pose")]
    stamps = [m.stamp_ns for m in robot_states]
    assert len(stamps) > 2 and all(np.diff(stamps) > 0)  # at set-up, along the move (sim time passes), at rest
    assert any(p == "truth/part_poses" for s, p, _ in msgs) and any(p == "scene" for s, p, _ in msgs)


def test_hand_eye_error_moves_the_observed_part():
    _, clean = run_cell()
    _, shifted = run_cell("{camera: {hand_eye_error: {translation_m: [0.002, 0, 0]}}}")
    a = next(m for s, p, m in clean if (s, p) == ("capture", "cloud")).points.mean(axis=0)
    b = next(m for s, p, m in shifted if (s, p) == ("capture", "cloud")).points.mean(axis=0)
    assert abs(np.linalg.norm(a - b) - 0.002) < 3e-4  # the camera believes itself 2 mm away from where it is


def test_unreachable_photo_pose_raises_an_alarm_and_captures_nothing():
    summary, msgs = run_cell(x=-2.5)
    alarms = [e for e in summary.events if e.level == "alarm"]
    assert alarms and alarms[0].code == "robot_refused" and "unreachable" in alarms[0].message
    assert not [1 for s, p, _ in msgs if (s, p) == ("capture", "cloud")]
    assert not [1 for s, p, _ in msgs if (s, p) == ("camera", "cloud")]


def test_solvers_and_actions_never_see_truth():
    base = CELL.format(effects="{}", count=1, x=-0.49)
    cheat_port = base + "  cheat: {type: transform_cloud, inputs: {cloud: camera.truth/part_poses}}\n"
    with pytest.raises(RecipeError) as info:
        graph_from(cheat_port)
    assert any("ground truth" in str(p) for p in info.value.problems)
    cheat_service = base.replace(
        "uses: {robot: robot.move, camera: camera.capture}", "uses: {robot: robot.truth, camera: camera.capture}"
    )
    with pytest.raises(RecipeError) as info:
        graph_from(cheat_service)
    assert any(
        "robot.truth gives simulation ground truth" in str(p) and "action" in str(p) for p in info.value.problems
    )


def test_the_cloud_port_can_show_a_thinned_copy_of_each_capture():
    """``cloud_decimate: 4``: the capture reply keeps every point, the cloud port (the recording's 3D
    view) every 4th, in the same frame with the same stamp."""
    keep = Keep()
    text = CELL.format(effects="{}", count=1, x=-0.49)
    summary = Runner(graph_from(text, ["camera.cloud_decimate=4"]), observers=[keep]).run()
    assert summary.ok, summary.stop_reason
    reply = next(m for s, p, m in keep.msgs if (s, p) == ("capture", "cloud"))
    shown = next(m for s, p, m in keep.msgs if (s, p) == ("camera", "cloud"))
    assert len(reply.points) > 2000 and (shown.frame_id, shown.stamp_ns) == (reply.frame_id, reply.stamp_ns)
    np.testing.assert_array_equal(shown.points, reply.points[::4])


def test_truth_goes_under_its_own_frame_names_beside_the_nominal_tree():
    """``truth/part_poses`` names ``truth/<frame>`` under ``world``: the nominal ``tcp``, ``camera`` and
    ``part`` of ``frames`` keep one parent and one pose each in a recording's 3D view."""
    summary, msgs = run_cell()
    assert summary.ok, summary.stop_reason
    truth = next(m for s, p, m in msgs if (s, p) == ("camera", "truth/part_poses"))
    nominal = next(m for s, p, m in msgs if (s, p) == ("camera", "frames"))
    assert {(t.frame_id, t.child_frame_id) for t in truth.transforms} == {
        ("world", "truth/part"),
        ("world", "truth/camera"),
        ("world", "truth/tcp"),
    }
    assert {(t.frame_id, t.child_frame_id) for t in nominal.transforms} == {("world", "part"), ("tcp", "camera")}


@pytest.mark.parametrize("name", ["base", "tcp", "world", "camera", "truth/part"])
def test_a_part_named_like_a_frame_of_the_cell_is_refused(name):
    text = CELL.format(effects="{}", count=1, x=-0.49).replace("{name: part,", f"{{name: {name},")
    with pytest.raises(RecipeError) as info:
        graph_from(text)
    assert any("a frame the cell already has" in str(p) for p in info.value.problems)
