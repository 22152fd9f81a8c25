"""A topic's quality of service as a recipe writes it, and the rclpy ``QoSProfile`` it stands for.

``qos: sensor_data`` is ROS 2's sensor profile (best effort, keep the last 5): what camera drivers
publish clouds and images with, and what a subscriber must use to hear a best-effort publisher.
``reliable`` (keep the last ``depth``, volatile) suits commands, joint states and results;
``static`` (reliable, transient local, depth 1) is the profile of ``/tf_static``: a node that joins
later still gets the last message. A mapping sets each policy itself::

    qos: {reliability: best_effort, durability: volatile, depth: 2}

A best-effort subscriber hears a reliable publisher, not the other way round; a transient-local
subscriber needs a transient-local publisher (ROS 2's QoS compatibility rules, docs.ros.org
"Quality of Service settings").
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

Preset = Literal["sensor_data", "reliable", "static"]


class QosPolicy(BaseModel):
    """The policies of one topic's QoS profile."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    depth: int = Field(10, ge=1, le=1000, description="messages kept (history keep-last)")


PRESETS: dict[str, QosPolicy] = {
    "sensor_data": QosPolicy(reliability="best_effort", durability="volatile", depth=5),
    "reliable": QosPolicy(reliability="reliable", durability="volatile", depth=10),
    "static": QosPolicy(reliability="reliable", durability="transient_local", depth=1),
}

Qos = Preset | QosPolicy


def policy_of(qos: Qos) -> QosPolicy:
    """The policies a preset name or a mapping stands for."""
    return PRESETS[qos] if isinstance(qos, str) else qos


def profile(qos: Qos) -> Any:
    """The rclpy ``QoSProfile`` of *qos* (rclpy imported here: only a running bridge needs it)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    p = policy_of(qos)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=p.depth,
        reliability=ReliabilityPolicy.RELIABLE if p.reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE if p.durability == "volatile" else DurabilityPolicy.TRANSIENT_LOCAL,
    )
