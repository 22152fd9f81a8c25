"""Every stage of the simulated cell publishes its frames: a recording shows the whole cell in 3D.

A recorded run with every simulated device (robot, a camera on the flange, a fixed camera seeing a
part in the gripper, a Vive tracker on the TCP, a point instrument) is read back: every transform
it holds (``frames`` ports, the cameras' truth under ``truth/<frame>``) forms one tree rooted at
``world`` (no frame with two parents), and every frame id that any message names (clouds, images,
poses, tracker readings, scene meshes, service replies) hangs in it. A tracker that is only sampled is not on the frames (see ``sim_tracker``); a streaming
one is, with each reading.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from frame_tree_helpers import ROBOT_FRAMES, record, sound_frame_tree
from recipe_helpers import header, stages

from engine.messages import codec
from engine.recording.reader import load

pytestmark = pytest.mark.timeout(180)

CELL = header("frame_tree", seed=5, clock="sim") + stages("""
  robot: {type: sim_robot, params: {model: ur5e}}
  hand_camera:
    type: sim_camera
    uses: {robot: robot.truth}
    params:
      intrinsics: {width: 64, height: 48}
      mount: {kind: eye_in_hand, pose: {xyz_m: [0.0, 0.06, 0.03]}}
      parts: [{name: part, workpiece: feature_part, pose: {xyz_m: [-0.49, -0.08, 0.0]}}]
  fixed_camera:
    type: sim_camera
    uses: {robot: robot.truth}
    params:
      frame_id: fixed_camera
      intrinsics: {width: 64, height: 48}
      mount: {kind: eye_to_hand, pose: {xyz_m: [-0.45, -0.15, 0.0], rpy_deg: [0, 0, 0]}}
      parts: [{name: held, workpiece: planar_plate, parent: tcp, pose: {xyz_m: [0, 0, 0.05]}}]
  vive:
    type: sim_tracker
    uses: {robot: robot.truth}
    params: {T_tcp_tracker: {xyz_m: [0.02, 0.0, -0.1]}}
  laser:
    type: sim_point_tracker
    uses: {robot: robot.truth}
    params: {frame_id: laser_tracker}
  start: {type: trigger, params: {count: 1}}
  poses:
    type: calibration_poses
    inputs: {trigger: start.out}
    uses: {robot: robot.move, point: laser.measure, tracker: vive.sample, camera: hand_camera.capture}
    params:
      poses: [{matrix: [[0, 1, 0, -0.49], [1, 0, 0, -0.14], [0, 0, -1, 0.45], [0, 0, 0, 1]]},
              {matrix: [[0, 1, 0, -0.45], [1, 0, 0, -0.10], [0, 0, -1, 0.40], [0, 0, 0, 1]]}]
      sensors: [point, tracker, camera]
  capture:
    type: capture_at_pose
    inputs: {trigger: poses.done}
    uses: {robot: robot.move, camera: fixed_camera.capture}
    params: {photo_pose: {matrix: [[1, 0, 0, -0.45], [0, -1, 0, -0.15], [0, 0, -1, 0.35], [0, 0, 0, 1]]}}
""")


# A tracker streaming on its own (its readings are published: they go on frames too); held in a
# fixture, as streaming next to a moving robot would advance the one simulated clock twice.
STREAMING = header("frame_tree_stream", seed=6, clock="sim") + stages("""
  robot: {type: sim_robot, params: {model: ur5e}}
  vive:
    type: sim_tracker
    params: {stream_hz: 50, duration_s: 0.2, T_world_tcp: {xyz_m: [0.3, 0.1, 0.5]}, tracker_frame: vive_tracker}
""")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    return record(CELL, tmp_path_factory.mktemp("frames") / "cell.mcap", ["builtin"])


@pytest.fixture(scope="module")
def streaming(tmp_path_factory):
    return record(STREAMING, tmp_path_factory.mktemp("frames") / "stream.mcap", ["builtin"])


def test_every_frame_named_in_a_recording_of_the_simulated_cell_hangs_in_one_tree_under_world(cell):
    tree = sound_frame_tree(cell)
    assert tree.parent_of() == {
        **ROBOT_FRAMES,
        "camera": "tcp",
        "part": "world",
        "fixed_camera": "world",
        "held": "tcp",
        "lighthouse": "world",  # the sampled tracker: its readings are replies, not on frames
        "laser_tracker": "world",
        # where the cameras saw the parts, the camera and the TCP truly were, beside the nominal frames
        **{f"truth/{f}": "world" for f in ("part", "camera", "tcp", "held", "fixed_camera")},
    }
    # each device publishes its own part of the tree
    by_stage = {edge: {t.split("/")[1] for t in topics} for edge, topics in tree.edges_by.items()}
    assert by_stage[("world", "base")] == by_stage[("base", "tcp")] == {"robot"}
    assert by_stage[("tcp", "camera")] == {"hand_camera"} and by_stage[("world", "fixed_camera")] == {"fixed_camera"}
    assert by_stage[("world", "lighthouse")] == {"vive"} and by_stage[("world", "laser_tracker")] == {"laser"}
    assert {"camera", "fixed_camera", "lighthouse", "laser_tracker", "held", "part"} <= set(tree.named_by)


def test_a_streaming_tracker_puts_each_reading_on_the_frames(streaming):
    tree = sound_frame_tree(streaming)
    assert tree.parent_of() == {**ROBOT_FRAMES, "lighthouse": "world", "vive_tracker": "lighthouse"}
    rec = load(streaming)

    def decoded(port):
        return [
            codec.decode_payload(codec.registry.get(m.type_name), m.payload)
            for m in rec.messages()
            if (m.stage, m.port) == ("vive", port)
        ]

    poses, frames = decoded("pose"), decoded("frames")
    assert len(poses) == 10 and len(frames) == 11  # 50 Hz for 0.2 s, and one at set-up
    for pose, f in zip(poses, frames[1:], strict=True):
        edge = f.transforms[1]
        assert (edge.frame_id, edge.child_frame_id) == ("lighthouse", "vive_tracker") and edge.stamp_ns == f.stamp_ns
        np.testing.assert_allclose(edge.T, pose.T, atol=1e-6)  # the reading itself (float32 quaternion aside)


GOLDEN = sorted((Path(__file__).resolve().parents[2] / "recordings").glob("*.mcap"))


@pytest.mark.parametrize("path", GOLDEN, ids=lambda p: p.stem)
def test_every_shipped_recording_draws_one_tree_under_world(path):
    """What Foxglove draws from a shipped recipe's recording: each frame one parent, every frame a
    message names connected to ``world`` (the demo's cloud used to hang in an unconnected 'camera')."""
    assert GOLDEN, "no recordings shipped"
    sound_frame_tree(path)
