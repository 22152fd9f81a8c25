"""The ROS 2 bridge stages and the cell gateway against plain rclpy nodes: topics into a recorded
vgr run that replays with rclpy unimportable, a malformed cloud that fails alone, a refused
correction never published, and the gateway's Trigger services and topics."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine.cli.main import main
from engine.messages import Correction
from plugins.ros2.gateway import start_gateway
from plugins.ros2.inbox import Inbox, NoMessageError
from plugins.ros2.publisher_stage import Ros2Publish
from plugins.ros2.subscriber_stage import Ros2SubscribeParams
from plugins.util.detached import detached_stage
from ros2.ros_peer import RosPeer, cloud_message, new_domain, wait_for

ROOT = Path(__file__).resolve().parents[2]
JOINTS = ["j1", "j2", "j3"]

RECIPE = """
name: ros2_topics_in
stages:
  ros:
    type: ros2_subscribe
    params:
      ros: {{domain_id: {domain}, discovery: localhost}}
      topics: {{cloud: {{topic: /cam/points, qos: sensor_data}}, joint_state: {{topic: /joint_states}}}}
      max_messages: {count}
      duration_s: 60
  move:
    type: transform_cloud
    inputs: {{cloud: ros.cloud}}
    params: {{translation_m: [0.1, 0, 0]}}
"""


def _publish_until(peer: RosPeer, stop: list[bool], pub_cloud: Any, msgs: list[Any], period_s: float = 0.05) -> None:
    """Publish *msgs* in turn on *pub_cloud* until *stop* is set (a driver that keeps streaming)."""
    i = 0
    while not stop and i < 2000:
        pub_cloud.publish(msgs[i % len(msgs)])
        i += 1
        time.sleep(period_s)


def test_topics_into_a_recorded_run_that_replays_without_rclpy(tmp_path: Path) -> None:
    import threading

    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    domain = new_domain()
    recipe = tmp_path / "in.yaml"
    recipe.write_text(RECIPE.format(domain=domain, count=6))
    pts = np.random.default_rng(1).uniform(-1, 1, (50, 3)).astype(np.float32)
    good = cloud_message(pts, "camera")
    bad = cloud_message(pts, "camera")
    bad.data = bytes(good.data)[:-5]  # truncated: a conversion error, and the stream goes on
    peer = RosPeer(domain, "driver")
    stop: list[bool] = []
    try:
        pub = peer.node.create_publisher(PointCloud2, "/cam/points", qos_profile_sensor_data)
        peer.joints(JOINTS, np.array([0.1, 0.2, 0.3]))
        thread = threading.Thread(target=_publish_until, args=(peer, stop, pub, [good, bad]), daemon=True)
        thread.start()
        record = tmp_path / "run.mcap"
        code = main(["run", str(recipe), "--record", str(record), "--no-progress", "--runs-dir", str(tmp_path)])
    finally:
        stop.append(True)
        peer.close()
    assert code == 0
    from engine.messages import Event, PointCloud
    from engine.messages.codec import decode_payload
    from engine.recording.reader import load

    rec = load(record)
    clouds = [decode_payload(PointCloud, m.payload) for m in rec.messages("/ros/cloud")]
    assert clouds and all(np.array_equal(c.points, pts) for c in clouds)
    assert rec.messages("/move/cloud")
    events = [decode_payload(Event, m.payload) for m in rec.messages("/ros/events")]
    errors = [e for e in events if e.code == "ros2_conversion"]
    assert errors and "/cam/points" in errors[0].message and "data" in errors[0].message
    # replay where rclpy cannot even be imported: the source is fed from the file, never constructed
    code_text = (
        "import sys; sys.modules['rclpy'] = None; from engine.cli.main import main; sys.exit(main(sys.argv[1:]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code_text, "replay", str(record), "--json", "--runs-dir", str(tmp_path / "r")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    doc = json.loads(out.stdout)
    assert out.returncode == 0 and doc["outcome"] == "ok", out.stderr[-3000:]


def test_a_refused_correction_is_never_published_an_accepted_one_is_a_pose_and_tf() -> None:
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage

    domain = new_domain()
    peer = RosPeer(domain, "listener")
    poses, tfs = peer.collect(PoseStamped, "/vgr/correction"), peer.collect(TFMessage, "/tf", 100)
    params = {
        "ros": {"domain_id": domain, "discovery": "localhost"},
        "type": "geometry_msgs/msg/PoseStamped",
        "topic": "/vgr/correction",
        "frame_id": "base_link",
        "tf_child_frame": "vgr_correction",
    }
    stage = detached_stage(Ros2Publish, "to_ros", params)
    try:
        T = np.eye(4)
        T[:3, 3] = [0.001, -0.002, 0.0]
        deadline = time.monotonic() + 10
        while stage.publisher.get_subscription_count() < 1 and time.monotonic() < deadline:  # type: ignore[attr-defined]
            time.sleep(0.05)
        stage.on_message("in", Correction(T=T, verdict="out_of_limits", frame_id="base"))
        time.sleep(0.5)
        assert poses == [] and tfs == []
        assert [e.code for e in stage.ctx.events] == ["correction_refused"]  # type: ignore[attr-defined]
        stage.on_message("in", Correction(T=T, verdict="ok", frame_id="base"))
        pose = wait_for(poses, 10.0, "the pose")
        assert pose.header.frame_id == "base_link"
        assert (pose.pose.position.x, pose.pose.position.y) == (0.001, -0.002)
        edge = wait_for(tfs, 10.0, "the transform").transforms[0]
        assert (edge.header.frame_id, edge.child_frame_id) == ("base_link", "vgr_correction")
    finally:
        stage.teardown()
        peer.close()


def test_the_gateway_takes_the_latest_joints_and_answers_on_trigger_and_topics() -> None:
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    domain = new_domain()
    seen: list[tuple[str, dict[str, Any]]] = []

    def handle(command: str, doc: dict[str, Any]) -> dict[str, Any]:
        seen.append((command, doc))
        correction = {"xyz_m": [0.002, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 1.0]}
        return {"command": command, "status": "ok", "result": {"parts": [{"correction": correction}]}}

    settings = {"ros": {"domain_id": domain, "discovery": "localhost"}, "joint_names": ["j3", "j1"]}
    gateway = start_gateway(handle, settings)
    peer = RosPeer(domain, "controller")
    try:
        replies = peer.collect(String, "/vgr/reply")
        no_joints = peer.call(Trigger, "/vgr/locate", timeout_s=20.0)
        assert not no_joints.success and "/joint_states" in no_joints.message and seen == []
        peer.joints(JOINTS, np.array([0.1, 0.2, 0.3]))
        deadline = time.monotonic() + 10
        while gateway.joints.latest() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        response = peer.call(Trigger, "/vgr/locate", timeout_s=20.0)
        assert response.success and json.loads(response.message)["status"] == "ok"
        assert seen[-1][0] == "locate" and seen[-1][1]["joints_rad"] == [0.3, 0.1]  # in joint_names' order
        request = String(data=json.dumps({"command": "guide", "id": "g-1", "step": 0}))
        pub = peer.node.create_publisher(String, "/vgr/request", 10)
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        pub.publish(request)
        reply = json.loads(wait_for(replies, 10.0, "a reply on /vgr/reply").data)
        assert reply["status"] == "ok" and seen[-1] == ("guide", {"id": "g-1", "step": 0})
        pub.publish(String(data="not json"))
        deadline = time.monotonic() + 10
        while len(replies) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert json.loads(replies[1].data)["status"] == "invalid_request"
    finally:
        peer.close()
        gateway.close()


def test_bad_settings_and_an_empty_topic_say_what_is_wrong() -> None:
    with pytest.raises(ValueError, match="ros2 gateway settings: namespace"):
        start_gateway(lambda c, d: {}, {"namespace": "no slash"})
    with pytest.raises(ValueError, match="no output port"):
        Ros2SubscribeParams.model_validate({"topics": {"clouds": {"topic": "/x"}}})
    inbox = Inbox("/camera/points")
    with pytest.raises(NoMessageError, match="/camera/points"):
        inbox.fresh(0.05)
    inbox.put(b"abc")
    assert inbox.latest() is not None and inbox.latest().number == 1  # type: ignore[union-attr]
    with pytest.raises(NoMessageError, match="1 received in all"):
        inbox.fresh(0.05)
