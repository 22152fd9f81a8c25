"""The real adapters publish their frames: a recording of a cell shows it in 3D, as the simulated one does.

Recorded runs with the SDKs faked at the adapter boundary: the UR robot (world -> base -> tcp), a
file camera on the flange (tcp -> camera: ``T_parent_cam``), a Vive tracker (world -> lighthouse ->
tracker) and a RealSense camera fixed in the cell (world -> camera). The transforms on the
``frames`` ports form one tree under ``world`` that holds every frame any message names.
"""

from __future__ import annotations

import numpy as np
import pytest
from adapter_recipes import SIM_PHOTO, adapter_header, capture_at_pose, ur_robot
from fake_openvr import FakeDevice, FakeOpenVR
from fake_openvr import install as install_openvr
from fake_realsense import FakeCamera, Intrinsics
from fake_realsense import install as install_realsense
from fake_ur_rtde import WORKSPACE, FakeURController, matrix_yaml, photo_pose
from fake_ur_rtde import install as install_ur
from frame_tree_helpers import ROBOT_FRAMES, record, sound_frame_tree
from recipe_helpers import stages
from shared_data import SHARED

from engine import transforms as tf
from engine.messages import codec
from engine.recording.reader import load

pytestmark = pytest.mark.timeout(180)

PLUGINS = ["builtin", "adapter_fixtures"]  # what the recordings list
PCL = SHARED / "pcl"


def ur_cell(photo: str) -> str:
    """The UR robot placed in the world, the file camera on its flange and a Vive tracker: 2 captures
    at *photo* (a YAML matrix) and 2 tracker samples."""
    return adapter_header("ur_cell", "adp-frames") + stages(
        ur_robot(WORKSPACE + ", T_world_base: {xyz_m: [0.1, 0.2, 0.8]}"),
        f"""
        camera:
          type: file_camera
          params: {{folder: {PCL}, pattern: "*.pcd", parent_frame: tcp, T_parent_cam: {{xyz_m: [0.0, 0.06, 0.03]}}}}
        tracker:
          type: vive_tracker
          params:
            serial: LHR-TRACK01
            stream_hz: 10
            duration_s: 0.5
            T_parent_lighthouse: {{xyz_m: [1.0, -0.5, 2.0], rpy_deg: [90, 0, 0]}}
        """,
        capture_at_pose(photo, count=2),
        """
        sampler:
          type: ta_tracker_sampler
          inputs: {trigger: start.out}
          uses: {tracker: tracker.sample}
        """,
    )


SIM_ROBOT_REALSENSE = adapter_header("sim_rs_frames") + stages(
    """
    robot: {type: sim_robot, params: {model: ur5e}}
    camera:
      type: realsense_camera
      params:
        width: 80
        height: 60
        warmup_frames: 2
        frame_id: fixed_camera
        T_parent_cam: {xyz_m: [-0.5, -0.1, 1.2], rpy_deg: [180, 0, 0]}
    """,
    capture_at_pose(SIM_PHOTO, count=1),
)


def edges(path, stage: str) -> list[tuple[str, str, np.ndarray]]:
    rec = load(path)
    out = []
    for m in rec.messages():
        if (m.stage, m.port) == (stage, "frames"):
            msg = codec.decode_payload(codec.registry.get(m.type_name), m.payload)
            out += [(t.frame_id, t.child_frame_id, t.T) for t in msg.transforms]
    return out


def test_ur_robot_file_camera_on_the_flange_and_vive_tracker_make_one_tree(monkeypatch, tmp_path):
    ctl = FakeURController()
    install_ur(monkeypatch, ctl)
    T_lh_tracker = tf.T_from_rotvec([0.1, 0.2, -0.3], [0.4, 1.1, -1.5])
    install_openvr(monkeypatch, FakeOpenVR(devices={3: FakeDevice("LHR-TRACK01", T=T_lh_tracker)}))
    path = record(ur_cell(matrix_yaml(photo_pose(ctl))), tmp_path / "ur_cell.mcap", PLUGINS)
    tree = sound_frame_tree(path)
    assert tree.parent_of() == {**ROBOT_FRAMES, "camera": "tcp", "lighthouse": "world", "tracker": "lighthouse"}
    cam = edges(path, "camera")
    assert len(cam) == 3  # at set-up and with each of the 2 captures
    for parent, child, T in cam:
        assert (parent, child) == ("tcp", "camera")
        np.testing.assert_allclose(T, tf.T_from_Rt(np.eye(3), [0.0, 0.06, 0.03]), atol=1e-12)
    tracker = [e for e in edges(path, "tracker") if e[1] == "tracker"]
    assert len(tracker) >= 5  # every streamed reading (samples after the stream are replies only)
    for _, _, T in tracker:
        assert tf.pose_error(T, T_lh_tracker)[0] < 1e-6


def test_realsense_camera_fixed_in_the_cell(monkeypatch, tmp_path):
    z16 = np.full((60, 80), 600, np.uint16)
    cam = FakeCamera(frames=[z16, z16], intrinsics=Intrinsics(80, 60, 70.0, 70.0, 39.5, 29.5))
    install_realsense(monkeypatch, cam)
    path = record(SIM_ROBOT_REALSENSE, tmp_path / "rs.mcap", PLUGINS)
    tree = sound_frame_tree(path)
    assert tree.parent_of() == {**ROBOT_FRAMES, "fixed_camera": "world"}
    assert "fixed_camera" in tree.named_by and any("cloud" in t or "srv" in t for t in tree.named_by["fixed_camera"])


@pytest.mark.parametrize(
    ("cls", "params", "expect"),
    [
        ("file_camera", {"folder": "/tmp", "parent_frame": "camera"}, "parent_frame must differ"),
        ("realsense_camera", {"frame_id": "world"}, "parent_frame must differ"),
        ("vive_tracker", {"tracker_frame": "lighthouse"}, "must differ"),
    ],
)
def test_a_frame_cannot_be_its_own_parent(cls, params, expect):
    from pydantic import ValidationError

    from engine.plugin_manager import load_registry

    with pytest.raises(ValidationError, match=expect):
        load_registry().stages[cls].Params(**params)
