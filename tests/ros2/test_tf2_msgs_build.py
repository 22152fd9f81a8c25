"""tools/build_tf2_msgs.py: the locally built tf2_msgs is a real ROS 2 message package.

No ``ros-tf2-msgs`` wheel exists, so the tool generates tf2_msgs from its definitions with
the installed rosidl generators.  These tests check what a stock ROS 2 peer relies on: the
DDS type name, the RIHS01 type hash and the CDR bytes (against rosbags, which carries its own
copy of the upstream definitions), and a plain rclpy ``/tf`` subscriber, typed and raw.

Skipped without rclpy; skipped without tf2_msgs (``make test`` runs the tool first)."""

from __future__ import annotations

import functools
import importlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("rclpy", reason="the ros2 extra (ros-rclpy) is not installed")
pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs is not built: run tools/build_tf2_msgs.py")

from geometry_msgs.msg import TransformStamped
from rclpy.serialization import deserialize_message, serialize_message
from tf2_msgs.msg import TF2Error, TFMessage

from ros2.ros_peer import RosPeer, new_domain, wait_for

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "build_tf2_msgs.py"
TFMESSAGE_RIHS01 = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"  # upstream Kilted


@functools.cache
def _tool() -> Any:
    """The tool's self-test helpers (tools/tf2_msgs_build/cdr.py: sample message, padding, rosbags bytes).

    Imported as tools/build_tf2_msgs.py imports its package: with tools/ on ``sys.path``.
    """
    if str(TOOL.parent) not in sys.path:
        sys.path.insert(0, str(TOOL.parent))
    return importlib.import_module("tf2_msgs_build.cdr")


def test_the_messages_have_the_upstream_fields_and_constants() -> None:
    assert TFMessage.get_fields_and_field_types() == {"transforms": "sequence<geometry_msgs/TransformStamped>"}
    assert TF2Error.get_fields_and_field_types() == {"error": "uint8", "error_string": "string"}
    assert (TF2Error.NO_ERROR, TF2Error.LOOKUP_ERROR, TF2Error.TRANSFORM_ERROR) == (0, 1, 6)


def test_the_dds_type_name_is_the_stock_one() -> None:
    assert _tool().dds_type_name() == "tf2_msgs::msg::dds_::TFMessage_"


def test_the_cdr_matches_rosbags_except_alignment_padding() -> None:
    tool = _tool()
    msg = tool.sample_message()
    ours = bytes(serialize_message(msg))
    assert deserialize_message(ours, TFMessage) == msg
    theirs = tool.rosbags_bytes(msg)
    if theirs is None:
        pytest.skip("rosbags is not installed")
    # Fast CDR leaves padding bytes as the buffer had them; rosbags writes zeros.
    assert tool.equal_except(ours, theirs, tool.tfmessage_padding(msg))
    assert len(ours) == len(theirs) == 196


def test_the_type_hash_is_the_upstream_one() -> None:
    import tf2_msgs

    share = Path(tf2_msgs.__file__).resolve().parents[4] / "share" / "tf2_msgs" / "msg" / "TFMessage.json"
    if not share.is_file():
        pytest.skip(f"tf2_msgs is not the one tools/build_tf2_msgs.py installs ({share} missing)")
    assert json.loads(share.read_text())["type_hashes"][0]["hash_string"] == TFMESSAGE_RIHS01


@pytest.mark.subprocess
def test_a_plain_rclpy_subscriber_gets_tf_typed_and_raw() -> None:
    domain = new_domain()
    talker, listener = RosPeer(domain, "tf_talker"), RosPeer(domain, "tf_listener")
    try:
        typed = listener.collect(TFMessage, "/tf")
        raw: list[bytes] = []
        listener.node.create_subscription(TFMessage, "/tf", raw.append, 10, raw=True)
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = "base", "tool0"
        t.transform.translation.x, t.transform.rotation.w = 0.25, 1.0
        msg = TFMessage(transforms=[t])
        pub = talker.node.create_publisher(TFMessage, "/tf", 10)
        talker.repeat(0.05, lambda: pub.publish(msg))
        assert wait_for(typed, 10.0, "TFMessage on /tf") == msg
        data = wait_for(raw, 10.0, "raw TFMessage on /tf")
        assert isinstance(data, bytes)
        assert deserialize_message(data, TFMessage) == msg
        names_types = dict(listener.node.get_topic_names_and_types())
        assert names_types["/tf"] == ["tf2_msgs/msg/TFMessage"]
        [info] = listener.node.get_publishers_info_by_topic("/tf")
        assert str(info.topic_type_hash) == TFMESSAGE_RIHS01
    finally:
        talker.close()
        listener.close()


@pytest.mark.subprocess
def test_the_tool_is_a_no_op_when_tf2_msgs_imports_and_its_self_test_passes() -> None:
    again = subprocess.run([sys.executable, str(TOOL)], capture_output=True, text=True, timeout=120, check=False)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "nothing to do" in again.stdout
    check = subprocess.run(
        [sys.executable, str(TOOL), "--verify", "--domain-id", str(new_domain())],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert check.returncode == 0, check.stdout + check.stderr
    assert "verification OK" in check.stdout
