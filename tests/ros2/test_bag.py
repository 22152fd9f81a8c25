"""``vgr bag export`` / ``vgr bag import``: the golden recording through a rosbag2 and back bit for
bit; a bag written by ``rosbags`` (sqlite3 and MCAP storage, standard types) imported for a recipe
and replayed through it; unconvertible topics and messages skipped with a note; --json documents
valid against their schemas; outputs never replaced, never written through a link."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from engine import transforms as tf
from engine.cli.json_output import schema
from engine.cli.main import main
from engine.messages import JointState, PointCloud
from engine.recording.reader import load
from engine.recording.replay import replay
from plugins.ros2.convert import encode
from plugins.ros2.convert_common import ros_class, typestore

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "recordings" / "eye_in_hand_dock.mcap"
ROUND_TRIP = ["/camera/cloud", "/camera/frames", "/robot/tcp_pose", "/robot/joint_state", "/robot/frames",
              "/robot/truth/tcp_pose", "/camera/truth/part_poses"]  # fmt: skip


def run_json(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, dict]:
    code = main([*argv, "--json"])
    return code, json.loads(capsys.readouterr().out)  # strict: the whole of stdout is one document


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bags") / "dock"
    assert main(["bag", "export", str(GOLDEN), "-o", str(out)]) == 0
    return out


def test_golden_recording_through_a_bag_and_back_is_bit_exact(tmp_path, capsys):
    bag = tmp_path / "dock"
    code, doc = run_json(["bag", "export", str(GOLDEN), "-o", str(bag)], capsys)
    jsonschema.validate(doc, schema("bag_export"))
    assert code == 0 and doc["ok"] and doc["messages_written"] == 321
    skipped = {s["topic"] for s in doc["skipped"]}
    assert {"/docking/correction", "/guidance/events", "/guidance/_svc/camera"} <= skipped
    back = tmp_path / "back.mcap"
    code, doc = run_json(["bag", "import", str(bag), "-o", str(back)], capsys)
    jsonschema.validate(doc, schema("bag_import"))
    assert code == 0 and doc["storage"] == "mcap" and doc["messages_written"] == 321
    a, b = load(GOLDEN), load(back)
    for topic in ROUND_TRIP:
        ma, mb = a.messages(topic), b.messages(topic)
        assert len(ma) == len(mb) > 0, topic
        for x, y in zip(ma, mb, strict=True):
            assert (x.payload, x.seq, x.publish_time, x.log_time, x.type_name) == (
                y.payload, y.seq, y.publish_time, y.log_time, y.type_name), topic  # fmt: skip
    assert b.channels["/camera/cloud"]["schema"] == "foxglove.PointCloud"


def test_the_exported_bag_reads_with_rosbags_as_standard_messages(exported):
    with Reader(exported) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/camera/cloud"] == "sensor_msgs/msg/PointCloud2"
        assert types["/robot/frames"] == "tf2_msgs/msg/TFMessage"
        assert reader.message_count == 321
        conn = next(c for c in reader.connections if c.topic == "/camera/cloud")
        _, t, raw = next(iter(reader.messages(connections=[conn])))
        cloud = typestore().deserialize_cdr(raw, conn.msgtype)
    assert [f.name for f in cloud.fields] == ["x", "y", "z"] and cloud.point_step == 12
    first = load(GOLDEN).messages("/camera/cloud")[0]
    assert t == first.log_time
    assert cloud.header.stamp.sec * 10**9 + cloud.header.stamp.nanosec == first.publish_time
    meta = (exported / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in meta and "vgr.recording" in meta


# --------------------------------------------------------------------------- a bag of a ROS 2 cell

RECIPE = """\
vgr: 1
name: bag_replay
seed: 3
clock: sim
stages:
  ros:
    type: ros2_subscribe
    params:
      topics:
        cloud: {topic: /camera/depth/points}
        joint_state: {topic: /joint_states}
  move:
    type: transform_cloud
    inputs: {cloud: ros.cloud}
    params: {translation_m: [0.1, 0.0, 0.0], rotation_deg: [0.0, 0.0, 90.0]}
  stats:
    type: cloud_stats
    inputs: {cloud: move.cloud}
"""


def _clouds(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    return [rng.normal(size=(200, 3)).astype(np.float32) for _ in range(n)]


def write_cell_bag(path: Path, storage: StoragePlugin) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A bag as a ROS 2 cell records it: PointCloud2 (padded to 16 bytes) and JointState, plus a topic
    vgr does not convert and one truncated message."""
    from ros_msgs import cloud2

    store = typestore()
    clouds, joints = _clouds(3), []
    with Writer(path, version=9, storage_plugin=storage) as w:
        c = w.add_connection("/camera/depth/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        j = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        s = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        t0 = 1_700_000_100_000_000_000
        for k in range(12):
            q = np.full(6, 0.1 * k)
            joints.append(q)
            js = JointState(stamp_ns=t0 + k * 10**8, names=[f"joint{i}" for i in range(6)], positions=q)
            w.write(j, t0 + k * 10**8 + 1000, encode(js, "sensor_msgs/msg/JointState"))
            if k % 4 == 1:
                pts = clouds[k // 4]
                msg = cloud2({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}, point_step=16,
                             frame="camera_depth_optical_frame")  # fmt: skip
                msg.header.stamp = ros_class("builtin_interfaces/msg/Time")(sec=1_700_000_100, nanosec=k * 10**8)
                w.write(c, t0 + k * 10**8 + 2000, bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2")))
        w.write(s, t0, bytes(store.serialize_cdr(ros_class("std_msgs/msg/String")(data="hi"), "std_msgs/msg/String")))
        bad = encode(PointCloud(points=np.zeros((50, 3), np.float32)), "sensor_msgs/msg/PointCloud2")
        w.write(c, t0 + 2 * 10**9, bad[:-40])
    return clouds, joints


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP], ids=["sqlite3", "mcap"])
def test_a_cell_bag_imports_for_a_recipe_and_replays_through_it(tmp_path, capsys, storage):
    bag, recipe, out = tmp_path / "cell", tmp_path / "bag_replay.yaml", tmp_path / "cell.mcap"
    recipe.write_text(RECIPE)
    clouds, _ = write_cell_bag(bag, storage)
    code, doc = run_json(["bag", "import", str(bag), "-o", str(out), "--recipe", str(recipe),
                          "--frame", "camera_depth_optical_frame=camera"], capsys)  # fmt: skip
    jsonschema.validate(doc, schema("bag_import"))
    assert code == 0, doc
    assert doc["storage"] == ("sqlite3" if storage == StoragePlugin.SQLITE3 else "mcap")
    topics = {t["ros_topic"]: t for t in doc["topics"]}
    assert topics["/camera/depth/points"]["vgr_topic"] == "/ros/cloud"
    assert topics["/camera/depth/points"]["fed"] == ["move.cloud"]
    assert (topics["/camera/depth/points"]["messages"], topics["/camera/depth/points"]["failed"]) == (3, 1)
    assert topics["/joint_states"]["vgr_topic"] == "/ros/joint_state"
    assert doc["skipped"] == [
        {"topic": "/chatter", "type": "std_msgs/msg/String", "reason": "std_msgs/msg/String has no vgr conversion"}
    ]
    assert any("/camera/depth/points" in n and "message skipped" in n for n in doc["notes"]), doc["notes"]
    assert doc["deliveries"] == 3

    rec = load(out)
    recorded = [m.payload for m in rec.messages("/ros/joint_state")]
    assert len(recorded) == 12
    report, _, _ = replay(out)
    assert report.failures == [] and report.rerun == ["move", "stats"]
    moved = [o.msg for o in report.outputs["/move/cloud"]]
    T = tf.T_from_rotvec(np.radians([0, 0, 90.0]), [0.1, 0, 0])
    assert len(moved) == 3
    for got, pts in zip(moved, clouds, strict=True):
        np.testing.assert_allclose(got.points, tf.transform_points(T, pts), atol=1e-6)
        assert got.frame_id == "camera"
    if storage == StoragePlugin.MCAP:  # the workflow of docs/ros2.md: the first replay's outputs become golden
        assert main(["replay", str(out), "--update", "--runs-dir", str(tmp_path / "runs")]) == 0
        capsys.readouterr()
        code, doc = run_json(["replay", str(out), "--runs-dir", str(tmp_path / "runs")], capsys)
        assert (code, doc["outcome"]) == (0, "ok") and {v["verdict"] for v in doc["streams"]} == {"identical"}


def test_the_topic_option_chooses_the_port_and_a_wrong_one_is_refused(tmp_path, capsys):
    bag, out = tmp_path / "cell", tmp_path / "cell.mcap"
    write_cell_bag(bag, StoragePlugin.MCAP)
    code, doc = run_json(["bag", "import", str(bag), "-o", str(out), "--topic", "/joint_states=robot/joints"], capsys)
    assert code == 0
    assert {t["ros_topic"]: t["vgr_topic"] for t in doc["topics"]} == {
        "/camera/depth/points": "/camera/depth/points", "/joint_states": "/robot/joints"}  # fmt: skip
    recipe = tmp_path / "r.yaml"
    recipe.write_text(RECIPE)
    code, doc = run_json(["bag", "import", str(bag), "-o", str(tmp_path / "x.mcap"), "--recipe", str(recipe),
                          "--topic", "/joint_states=move/cloud"], capsys)  # fmt: skip
    jsonschema.validate(doc, schema("invalid"))
    assert code == 2 and "played-back stage" in doc["error"]
    assert not (tmp_path / "x.mcap").exists()


# --------------------------------------------------------------------------- refusals


def test_outputs_are_never_replaced_nor_written_through_a_link(tmp_path, capsys, exported):
    target = tmp_path / "precious"
    target.write_text("keep me")
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere")
    for argv in (
        ["bag", "import", str(exported), "-o", str(target)],
        ["bag", "import", str(exported), "-o", str(link)],
        ["bag", "export", str(GOLDEN), "-o", str(exported)],
        ["bag", "export", str(GOLDEN), "-o", str(dangling)],
    ):
        code, doc = run_json(argv, capsys)
        jsonschema.validate(doc, schema("invalid"))
        assert code == 2 and "exists" in doc["error"], doc
    assert target.read_text() == "keep me" and not (tmp_path / "nowhere").exists()


def test_invalid_inputs_and_nothing_to_convert(tmp_path, capsys):
    code, doc = run_json(["bag", "import", str(tmp_path / "no_bag"), "-o", str(tmp_path / "a.mcap")], capsys)
    jsonschema.validate(doc, schema("invalid"))
    assert code == 2 and "no_bag" in doc["error"]
    code, doc = run_json(["bag", "export", str(tmp_path / "none.mcap"), "-o", str(tmp_path / "b")], capsys)
    assert code == 2 and not (tmp_path / "b").exists()
    chatter = tmp_path / "chatter"
    with Writer(chatter, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        s = w.add_connection("/chatter", "std_msgs/msg/String", typestore=typestore())
        w.write(
            s, 1, bytes(typestore().serialize_cdr(ros_class("std_msgs/msg/String")(data="x"), "std_msgs/msg/String"))
        )
    code, doc = run_json(["bag", "import", str(chatter), "-o", str(tmp_path / "c.mcap")], capsys)
    jsonschema.validate(doc, schema("bag_import"))
    assert (code, doc["outcome"]) == (1, "empty") and doc["skipped"][0]["topic"] == "/chatter"
    assert not (tmp_path / "c.mcap").exists()
    silent = tmp_path / "silent"  # a convertible topic without a message: nothing written either
    with Writer(silent, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=typestore())
    code, doc = run_json(["bag", "import", str(silent), "-o", str(tmp_path / "d.mcap")], capsys)
    jsonschema.validate(doc, schema("bag_import"))
    assert (code, doc["outcome"]) == (1, "empty") and not (tmp_path / "d.mcap").exists()


def test_a_failed_export_leaves_no_folder(tmp_path, capsys):
    out = tmp_path / "strict"
    code, doc = run_json(["bag", "export", str(GOLDEN), "-o", str(out), "--frame", "base_link=base",
                          "--strict-frames"], capsys)  # fmt: skip
    jsonschema.validate(doc, schema("invalid"))
    assert code == 2 and "frame" in doc["error"] and "/robot/" in doc["error"]
    assert not out.exists()


def test_export_to_tf_static_is_latched_and_names_are_made_valid(tmp_path, capsys):
    from plugins.ros2.bag_export import ros_name

    assert ros_name("/cam-1/3d.points") == "/cam_1/_3d_points"
    out = tmp_path / "static"
    code, doc = run_json(["bag", "export", str(GOLDEN), "-o", str(out), "--topic", "camera/frames=/tf_static",
                          "--topic", "robot/frames=/tf"], capsys)  # fmt: skip
    assert code == 0
    with Reader(out) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert "/camera/frames" not in conns and conns["/tf"].msgcount == 78 and conns["/tf_static"].msgcount == 3
        (qos,) = conns["/tf_static"].ext.offered_qos_profiles
        assert qos.durability.name == "TRANSIENT_LOCAL"
    code, doc = run_json(["bag", "export", str(GOLDEN), "-o", str(tmp_path / "x"), "--topic", "robot/frames=/t-f"],
                         capsys)  # fmt: skip
    assert code == 2 and "not a ROS 2 topic name" in doc["error"]


def test_without_the_ros2_extra_the_verb_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "rosbags", None)  # (an import of it now fails, as when it is absent)
    monkeypatch.setitem(sys.modules, "rosbags.typesys", None)
    typestore.cache_clear()
    try:
        code, doc = run_json(["bag", "import", str(tmp_path / "bag"), "-o", str(tmp_path / "y.mcap")], capsys)
    finally:
        monkeypatch.undo()
        typestore.cache_clear()
    jsonschema.validate(doc, schema("invalid"))
    assert code == 2 and "pip install vgr[ros2]" in doc["error"]
