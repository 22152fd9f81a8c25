"""The round trip's two child processes: a TFMessage publisher and a typed + raw subscriber.

Both run as ``build_tf2_msgs.py --_publisher`` / ``--_subscriber`` (started by verify.verify);
the subscriber prints one JSON report line and exits 0 when every check passed.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Any

from .cdr import (
    EXPECTED_DDS_TYPE,
    dds_type_name,
    equal_except,
    rosbags_bytes,
    rosbags_store,
    sample_message,
    tfmessage_padding,
)
from .common import ENTRY_POINT
from .definitions import PACKAGE


def run_publisher(topic: str, timeout_s: float) -> int:
    """Child process: publish the sample TFMessage every 50 ms until terminated or timed out."""
    import rclpy
    from tf2_msgs.msg import TFMessage

    rclpy.init()
    node = rclpy.create_node("vgr_tf2_msgs_selftest_pub")
    pub = node.create_publisher(TFMessage, topic, 10)
    message = sample_message()
    deadline = time.monotonic() + timeout_s
    try:
        while rclpy.ok() and time.monotonic() < deadline:
            try:
                pub.publish(message)
            except Exception:
                if rclpy.ok():
                    raise
                break  # SIGTERM from the subscriber: rclpy's handler shut the context down
            time.sleep(0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def run_subscriber(topic: str, timeout_s: float) -> int:
    """Child process: subscribe typed and raw, start the publisher, print a JSON report."""
    from rclpy.serialization import deserialize_message, serialize_message
    from tf2_msgs.msg import TFMessage

    report: dict[str, object] = {"dds_type_name": dds_type_name()}
    expected = sample_message()
    padding = tfmessage_padding(expected)
    expected_bytes = bytes(serialize_message(expected))
    rb = rosbags_bytes(expected)
    store = rosbags_store()
    report["rosbags_available"] = store is not None
    if rb is not None and store is not None:
        report["rclpy_serialize_equals_rosbags_except_padding"] = equal_except(expected_bytes, rb, padding)
        report["rosbags_type_hash"] = str(store.hash_rihs01("tf2_msgs/msg/TFMessage"))

    received = _receive(topic, timeout_s, report)
    report["typed_received"] = "typed" in received
    report["typed_equal"] = received.get("typed") == expected
    raw = received.get("raw")
    report["raw_received"] = isinstance(raw, bytes)
    if isinstance(raw, bytes):
        report["raw_len"] = len(raw)
        report["raw_deserializes_equal"] = deserialize_message(raw, TFMessage) == expected
        report["raw_equals_rclpy_serialize_except_padding"] = equal_except(raw, expected_bytes, padding)
        if rb is not None and store is not None:
            report["raw_equals_rosbags_except_padding"] = equal_except(raw, rb, padding)
            report["raw_equals_rosbags_exactly"] = raw == rb
            decoded = store.deserialize_cdr(raw, "tf2_msgs/msg/TFMessage")
            report["rosbags_decodes_raw"] = _summary(decoded) == _summary(expected)
    print(json.dumps(report), flush=True)
    return 0 if _passed(report) else 1


def _receive(topic: str, timeout_s: float, report: dict[str, object]) -> dict[str, object]:
    """Subscribe typed and raw, start the publisher process, wait for one of each (or the timeout).

    Adds the elapsed time and what the ROS graph shows (topic type, announced type hashes) to report.
    """
    import rclpy
    from tf2_msgs.msg import TFMessage

    rclpy.init()
    node = rclpy.create_node("vgr_tf2_msgs_selftest_sub")
    received: dict[str, object] = {}

    def on_typed(message: object) -> None:
        received.setdefault("typed", message)

    def on_raw(data: object) -> None:
        received.setdefault("raw", data)

    node.create_subscription(TFMessage, topic, on_typed, 10)
    node.create_subscription(TFMessage, topic, on_raw, 10, raw=True)
    publisher = subprocess.Popen(
        [sys.executable, str(ENTRY_POINT), "--_publisher", "--topic", topic, "--timeout", str(timeout_s)],
    )
    started = time.monotonic()
    try:
        while len(received) < 2 and time.monotonic() - started < timeout_s:
            rclpy.spin_once(node, timeout_sec=0.1)
        report["elapsed_s"] = round(time.monotonic() - started, 3)
        report["graph_type"] = dict(node.get_topic_names_and_types()).get(topic)
        # The RIHS01 type hash the publisher announced in discovery (USER_DATA).
        report["type_hash"] = [str(info.topic_type_hash) for info in node.get_publishers_info_by_topic(topic)]
    finally:
        publisher.terminate()
        try:
            publisher.wait(timeout=5)
        except subprocess.TimeoutExpired:
            publisher.kill()
        node.destroy_node()
        rclpy.try_shutdown()
    return received


def _summary(message: Any) -> list[tuple[str, str, float]]:
    """Frames and x translation of each transform: what rosbags' decoding of the raw bytes is compared on."""
    return [(t.header.frame_id, t.child_frame_id, t.transform.translation.x) for t in message.transforms]


def _passed(report: dict[str, object]) -> bool:
    """Whether the report shows a stock round trip; the rosbags checks count only when rosbags is there."""
    hashes = report["type_hash"] if isinstance(report["type_hash"], list) else []
    checks = [
        report["dds_type_name"] == EXPECTED_DDS_TYPE,
        report["graph_type"] == [f"{PACKAGE}/msg/TFMessage"],
        report["typed_equal"],
        report.get("raw_deserializes_equal", False),
        report.get("raw_equals_rclpy_serialize_except_padding", False),
        report.get("rclpy_serialize_equals_rosbags_except_padding", True),
        report.get("raw_equals_rosbags_except_padding", True),
        report.get("rosbags_decodes_raw", True),
        report.get("rosbags_type_hash", hashes[0] if hashes else "none") in hashes,
    ]
    return all(checks)
