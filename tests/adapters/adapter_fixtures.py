"""Test stages that drive and observe device adapters inside a real vgr run (recipe ``plugins:``).

They use only the device contracts of plugins.interfaces (client side), so the same recipe text
works with a simulated twin or a real adapter in the device's place.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.hookspecs import hookimpl
from engine.messages import JointState, PointCloud, PoseStamped, Request, RobotCommand, TrackerPose
from engine.stage import ServiceError, Stage, StageParams
from plugins.interfaces import ROBOT_MOVE, ROBOT_STATE, TRACKER_SAMPLE

SEEN: dict[str, dict[str, list[Any]]] = defaultdict(lambda: defaultdict(list))  # run id -> stage -> items


class RobotScript(Stage):
    """On each trigger: read the state, then send each scripted command (offsets from that pose)."""

    type_name = "ta_robot_script"
    role = "action"
    inputs: ClassVar = {"trigger": Request}
    uses: ClassVar = {"robot": ROBOT_MOVE, "state": ROBOT_STATE}

    class Params(StageParams):
        steps: list[dict[str, Any]] = Field(default_factory=list, description="{id, kind, offset_m, speed}")

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        start = self.ctx.call("state", Request(command="now"))
        SEEN[self.ctx.run_id][self.ctx.name].append(("state", start.ok, start.T))
        for step in self.params.steps:  # type: ignore[attr-defined]
            T = np.array(start.T, dtype=float)
            T[:3, 3] += step.get("offset_m", (0.0, 0.0, 0.0))
            cmd = RobotCommand(
                command_id=step["id"],
                kind=step.get("kind", "move_l"),
                T=T,
                speed=step.get("speed", 0.0),
                frame_id="base",
            )
            try:
                r = self.ctx.call("robot", cmd)
                SEEN[self.ctx.run_id][self.ctx.name].append((r.command_id, r.ok, r.duplicate, r.error, r.T))
            except ServiceError as exc:
                SEEN[self.ctx.run_id][self.ctx.name].append((step["id"], "service_error", str(exc)))


class TrackerSampler(Stage):
    """On each trigger, samples the tracker and keeps the reading."""

    type_name = "ta_tracker_sampler"
    role = "action"
    inputs: ClassVar = {"trigger": Request}
    uses: ClassVar = {"tracker": TRACKER_SAMPLE}

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        SEEN[self.ctx.run_id][self.ctx.name].append(self.ctx.call("tracker", Request(command="sample")))


def _collector(type_name: str, msg_type: type) -> type[Stage]:
    class Collect(Stage):
        __doc__ = f"Keeps every {msg_type.__name__} it receives."
        role = "sink"
        inputs: ClassVar = {"in": msg_type}

        def on_message(self, port: str, msg: Any) -> None:
            SEEN[self.ctx.run_id][self.ctx.name].append(msg)

    Collect.type_name = type_name
    Collect.__name__ = f"Collect{msg_type.__name__}"
    return Collect


CollectCloud = _collector("ta_collect_cloud", PointCloud)
CollectPose = _collector("ta_collect_pose", PoseStamped)
CollectTracker = _collector("ta_collect_tracker", TrackerPose)
CollectJoints = _collector("ta_collect_joints", JointState)


@hookimpl
def vgr_stage_types() -> list[type]:
    return [RobotScript, TrackerSampler, CollectCloud, CollectPose, CollectTracker, CollectJoints]
