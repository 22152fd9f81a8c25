"""A plain rclpy node for the ROS 2 tests: the camera and robot drivers of a cell, and the node that
asks vgr for a correction, written with rclpy's own message classes only (never vgr's
conversions, so a test checks vgr against ROS 2 itself).

Every peer has a context of its own on a domain of its own (:func:`new_domain`), discovery on
this host only, and bounded waits."""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="the ros2 extra (ros-rclpy) is not installed")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from sensor_msgs.msg import JointState, PointCloud2, PointField  # noqa: E402

_domains = itertools.count()


def new_domain() -> int:
    """A ROS_DOMAIN_ID no other test of this session uses (100-199, spread by the process id)."""
    return 100 + (os.getpid() * 7 + next(_domains)) % 100


def cloud_message(points: np.ndarray, frame_id: str, stamp_ns: int = 0) -> Any:
    """An unorganised xyz float32 PointCloud2 of *points* (N, 3), padded to 16 bytes a point as
    camera drivers write them, little-endian."""
    n = len(points)
    packed = np.zeros((n, 4), np.float32)
    packed[:, :3] = points
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10**9)
    msg.height, msg.width = 1, n
    msg.fields = [PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, c in enumerate("xyz")]
    msg.is_bigendian, msg.point_step, msg.row_step, msg.is_dense = False, 16, 16 * n, True
    msg.data = packed.tobytes()
    return msg


class RosPeer:
    """A node of its own context, spun on a thread; closed by :meth:`close`."""

    def __init__(self, domain_id: int, name: str = "test_peer") -> None:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def repeat(self, period_s: float, publish: Callable[[], None]) -> None:
        """Call *publish* every *period_s* (a driver's stream)."""
        self.node.create_timer(period_s, publish)

    def camera(self, topic: str, points: np.ndarray, frame_id: str, period_s: float = 0.1) -> None:
        """A camera driver: the same cloud on *topic* every *period_s* (sensor-data QoS)."""
        pub = self.node.create_publisher(PointCloud2, topic, qos_profile_sensor_data)
        msg = cloud_message(points, frame_id)
        self.repeat(period_s, lambda: pub.publish(msg))

    def joints(self, names: list[str], q: np.ndarray, period_s: float = 0.05) -> None:
        """A robot driver: its joint states on /joint_states."""
        pub = self.node.create_publisher(JointState, "/joint_states", 10)

        def send() -> None:
            m = JointState()
            m.header.stamp = self.node.get_clock().now().to_msg()
            m.name, m.position = list(names), [float(v) for v in q]
            pub.publish(m)

        self.repeat(period_s, send)

    def collect(self, msg_class: Any, topic: str, qos: Any = 10) -> list[Any]:
        """Every message of *topic*, appended to the returned list as it arrives."""
        got: list[Any] = []
        self.node.create_subscription(msg_class, topic, got.append, qos)
        return got

    def call(self, srv_class: Any, name: str, timeout_s: float = 60.0) -> Any:
        """Call service *name* with an empty request; its response (AssertionError after *timeout_s*)."""
        client = self.node.create_client(srv_class, name)
        assert client.wait_for_service(timeout_sec=timeout_s), f"no service {name} within {timeout_s:g} s"
        future = client.call_async(srv_class.Request())
        deadline = time.monotonic() + timeout_s
        while not future.done():
            assert time.monotonic() < deadline, f"no response from {name} within {timeout_s:g} s"
            time.sleep(0.02)
        return future.result()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def wait_for(items: list[Any], timeout_s: float, what: str) -> Any:
    """The first of *items* once one has arrived (AssertionError naming *what* after *timeout_s*)."""
    deadline = time.monotonic() + timeout_s
    while not items:
        assert time.monotonic() < deadline, f"no {what} within {timeout_s:g} s"
        time.sleep(0.02)
    return items[0]
