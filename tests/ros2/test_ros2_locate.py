"""recipes/ros2_locate.yaml in a ROS 2 cell: plain rclpy nodes play the camera driver (PointCloud2)
and the robot driver (JointState), `vgr serve` locates the part when a ROS 2 node calls
``/vgr/locate`` (std_srvs/Trigger), and the correction comes back in the response, on
``/vgr/correction`` (PoseStamped) and on ``/tf`` — checked against the simulated truth."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from cell.service_helpers import Server, private_runtime_dir

from engine.run.cell.protocol import pose_from_doc
from engine.transforms import T_from_Rt, pose_error
from plugins.registration.template import load_template
from plugins.robot.model_file import load_robot_model
from plugins.sim.stages.camera import SimCamera
from plugins.util.detached import detached_stage
from ros2.ros_peer import RosPeer, new_domain, wait_for

pytestmark = pytest.mark.subprocess

ROOT = Path(__file__).resolve().parents[2]
RECIPE = ROOT / "recipes" / "ros2_locate.yaml"
TEMPLATE = ROOT / "recipes" / "templates" / "eye_in_hand.vgrtpl"
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
PART_NOMINAL = {"xyz_m": [-0.49, -0.08, 0.0], "rpy_deg": [0, 0, 10]}  # where the template saw the part
TRUE_MOUNT = {"xyz_m": [0.0, 0.06, 0.03]}  # the recipe's hand-eye is 0.98 mm / 0.49 deg off it


def _part_pose(dx_mm: float, dy_mm: float, dyaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The part's nominal pose and one moved by (dx, dy, dyaw) in the base frame."""
    from scipy.spatial.transform import Rotation

    nominal = T_from_Rt(Rotation.from_euler("z", 10, degrees=True).as_matrix(), PART_NOMINAL["xyz_m"])
    offset = T_from_Rt(Rotation.from_euler("z", dyaw_deg, degrees=True).as_matrix(), (dx_mm / 1e3, dy_mm / 1e3, 0))
    return nominal, offset @ nominal


def _capture(T_part: np.ndarray, T_base_tcp: np.ndarray) -> np.ndarray:
    """The simulated camera's cloud (camera frame, m) of the part at *T_part*, robot at *T_base_tcp*."""
    cam = detached_stage(
        SimCamera,
        "camera",
        {
            "noise": {"preset": "custom", "sigma_const_m": 0.0001, "depth_unit_m": 0.0001},
            "mount": {"kind": "eye_in_hand", "pose": TRUE_MOUNT},
            "parts": [{"name": "part", "workpiece": "feature_part", "pose": {"matrix": pose_doc_matrix(T_part)}}],
            "publish_depth": False,
        },
        seed=3,
    )
    capture, _truth = cam.cell.capture(T_base_tcp, cam.ctx.rng, 0.0)  # type: ignore[attr-defined]
    return np.asarray(capture.points, dtype=np.float32)


def pose_doc_matrix(T: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in T]


def _recipe_copy(folder: Path) -> Path:
    data = yaml.safe_load(RECIPE.read_text())
    data["vars"]["template"] = str(TEMPLATE)
    path = folder / "ros2_locate.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_ros2_node_gets_the_correction_of_a_ros2_camera_cloud(tmp_path: Path) -> None:
    from geometry_msgs.msg import PoseStamped
    from std_srvs.srv import Trigger

    T_photo = load_template(TEMPLATE).T_base_tcp_photo
    ik = load_robot_model("ur5e").ik(T_photo)
    assert ik.success, ik.reason
    nominal, moved = _part_pose(4.0, -3.0, 3.0)
    truth = moved @ np.linalg.inv(nominal)  # D = P P0^-1: what the taught poses must be corrected by
    points = _capture(moved, T_photo)

    domain = new_domain()
    peer = RosPeer(domain, "cell_drivers")
    server = Server(_recipe_copy(tmp_path), "ros2", tmp_path, private_runtime_dir(), "-p", f"vars.domain_id={domain}")
    try:
        peer.camera("/camera/depth/points", points, "camera_depth_optical_frame")
        peer.joints(JOINTS, ik.q)
        poses = peer.collect(PoseStamped, "/vgr/correction")
        tf_seen = None
        if importlib.util.find_spec("tf2_msgs") is not None:
            from tf2_msgs.msg import TFMessage

            tf_seen = peer.collect(TFMessage, "/tf", 100)
        server.wait_ready()
        response = peer.call(Trigger, "/vgr/locate", timeout_s=90.0)
        reply = json.loads(response.message)
        assert response.success, reply
        D = pose_from_doc(reply["result"]["parts"][0]["correction"], "correction")
        t, r = pose_error(D, truth)
        assert t < 1.0e-3 and np.degrees(r) < 0.2, (t * 1e3, np.degrees(r))  # mm and deg against the truth

        pose = wait_for(poses, 10.0, "PoseStamped on /vgr/correction")
        assert pose.header.frame_id == "base_link"
        p, q = pose.pose.position, pose.pose.orientation
        assert np.allclose([p.x, p.y, p.z], D[:3, 3], atol=1e-9)
        from scipy.spatial.transform import Rotation

        assert np.allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), D[:3, :3], atol=1e-9)
        if tf_seen is not None:
            tf = wait_for(tf_seen, 10.0, "TFMessage on /tf").transforms[0]
            assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "vgr_correction")
            assert np.allclose([tf.transform.translation.x, tf.transform.translation.y], D[:2, 3], atol=1e-9)
    finally:
        peer.close()
        server.send()
        server.wait()
