"""One ROS 2 node per process and domain, shared by every bridge stage and the cell gateway.

rclpy is imported here, lazily (:func:`plugins.util.sdk.import_sdk`: the ``ros2`` extra). The first
:func:`acquire` of a domain creates an rclpy ``Context`` of its own (never the global one, so vgr
and user code in the same process do not share a shutdown), initialised **without rclpy's signal
handlers**: Ctrl-C and SIGTERM stay vgr's, whose stop halts motion first (docs/design.md). A node
``vgr_<name>`` is spun by a single-threaded executor on a daemon thread; callbacks run there and
must only hand data over (every bridge callback stores the message's serialized bytes and returns).
The last :func:`release` destroys the node and shuts the context down.

Discovery: ``discovery: localhost`` sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` for the process
before the context starts (DDS then talks to this host only, as the tests do); ``subnet`` and
``system_default`` are ROS 2's other values; unset, the environment decides, as for any ROS 2 node.
The domain is ``domain_id`` or, unset, ``ROS_DOMAIN_ID`` (0 when that is unset too).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from plugins.util.sdk import import_sdk

Discovery = Literal["localhost", "subnet", "system_default"]
SPIN_S = 0.05  # the executor thread looks at close() this often


class RosSettings(BaseModel):
    """Which ROS 2 graph a stage joins: its domain, discovery range and namespace."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    domain_id: int | None = Field(None, ge=0, le=232, description="ROS_DOMAIN_ID (unset: the environment's, else 0)")
    discovery: Discovery | None = Field(
        None, description="ROS_AUTOMATIC_DISCOVERY_RANGE: localhost, subnet, system_default (unset: the environment's)"
    )
    namespace: str = Field("", description="ROS namespace of the node: relative topic names resolve inside it")


def rclpy_module(stage_type: str) -> Any:
    """rclpy, or a :class:`~plugins.util.sdk.MissingSDKError` naming the ``ros2`` extra."""
    return import_sdk("rclpy", stage_type=stage_type, extra="ros2", package="ros-rclpy")


def domain_of(settings: RosSettings) -> int:
    """The domain a node with *settings* joins."""
    if settings.domain_id is not None:
        return settings.domain_id
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return int(text) if text.isdigit() else 0


class RosNode:
    """A node of its own context, spun on a daemon thread; shared through :func:`acquire`."""

    def __init__(self, rclpy: Any, domain_id: int, namespace: str) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.rclpy = rclpy
        self.domain_id = domain_id
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f"vgr_{os.getpid()}", namespace=namespace or None, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f"ros2-domain-{domain_id}", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._closing.is_set() and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=SPIN_S)
            except Exception:  # the context was shut down under the spin: the node is closing
                if not self._closing.is_set():
                    raise
                return

    def subscribe_raw(self, msg_class: Any, topic: str, qos: Any, callback: Callable[[bytes], None]) -> Any:
        """A subscription that hands *callback* each message's serialized bytes (CDR with its
        encapsulation header), converted later on the stage's thread."""
        return self.node.create_subscription(msg_class, topic, callback, qos, raw=True)

    def publisher(self, msg_class: Any, topic: str, qos: Any) -> Any:
        """A publisher of *msg_class* on *topic*; ``publish(bytes)`` sends serialized messages."""
        return self.node.create_publisher(msg_class, topic, qos)

    def destroy(self, entity: Any) -> None:
        """Destroy a subscription or publisher this node made (ignored once the node is closed)."""
        if self._closing.is_set():
            return
        if hasattr(entity, "publish"):
            self.node.destroy_publisher(entity)
        else:
            self.node.destroy_subscription(entity)

    def close(self) -> None:
        self._closing.set()
        self._thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        if self.context.ok():
            self.rclpy.shutdown(context=self.context)


_lock = threading.Lock()
_nodes: dict[tuple[int, str], tuple[RosNode, int]] = {}


def acquire(settings: RosSettings, *, stage_type: str) -> RosNode:
    """The process's node for *settings*' domain and namespace (created on first use); pair with
    :func:`release`."""
    rclpy = rclpy_module(stage_type)
    key = (domain_of(settings), settings.namespace)
    with _lock:
        if key in _nodes:
            node, users = _nodes[key]
            _nodes[key] = (node, users + 1)
            return node
        if settings.discovery is not None:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = settings.discovery.upper()
        node = RosNode(rclpy, key[0], settings.namespace)
        _nodes[key] = (node, 1)
        return node


def release(node: RosNode) -> None:
    """One user fewer of *node*; the last one closes it."""
    with _lock:
        for key, (known, users) in list(_nodes.items()):
            if known is node:
                if users > 1:
                    _nodes[key] = (known, users - 1)
                    return
                del _nodes[key]
                break
        else:
            return
    node.close()
