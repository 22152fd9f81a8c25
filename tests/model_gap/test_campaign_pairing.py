"""The measurement campaign publishes a tracker reading only with the joints it was taken at: a
reply that is not a fresh arrival, or a reading older than the arrival, is skipped with a warning."""

from __future__ import annotations

from typing import Any

import numpy as np

from engine.messages import Message, Request, RobotReply, TrackerPose
from plugins.model_gap.stages.measurement_campaign import MeasurementCampaign
from plugins.util.detached import DetachedContext

MS = 1_000_000


class ScriptedCell(DetachedContext):
    """Answers the campaign's robot and tracker calls from scripts (one entry per call)."""

    def __init__(self, moves: list[dict[str, Any]], readings: list[int]) -> None:
        super().__init__("campaign", seed=1)
        self.moves, self.readings = list(moves), list(readings)

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        if client == "robot":
            kw = self.moves.pop(0)
            return RobotReply(command_id=request.command_id, ok=True, **kw)
        stamp = self.readings.pop(0)
        return TrackerPose(stamp_ns=stamp, frame_id="tracker", serial="t1", T=np.eye(4), valid=True)

    def has_client(self, client: str) -> bool:
        return True


def campaign(ctx: ScriptedCell, n: int) -> MeasurementCampaign:
    stage = MeasurementCampaign(ctx, MeasurementCampaign.Params.model_validate({"n_poses": n}))
    stage.setup()
    stage.on_message("trigger", Request(command="go", seq=1))
    return stage


def test_only_fresh_arrivals_with_fresh_readings_are_published():
    q = np.zeros(6)
    moves = [
        {"joints": q + 0.1, "stamp_ns": 100 * MS},  # fresh arrival, reading after it: kept
        {"joints": q + 0.2, "stamp_ns": 200 * MS, "duplicate": True},  # journal answer: no move now
        {"joints": None, "stamp_ns": 300 * MS},  # no joints to pair with
        {"joints": q + 0.4, "stamp_ns": 400 * MS},  # reading taken before the arrival: stale
        {"joints": q + 0.5, "stamp_ns": 500 * MS},  # kept
    ]
    readings = [150 * MS, 390 * MS, 510 * MS]  # only poses 0, 3 and 4 reach the tracker
    ctx = ScriptedCell(moves, readings)
    campaign(ctx, 5)
    joints = [m.positions for port, m in ctx.published if port == "joint_state"]
    meas = [m for port, m in ctx.published if port == "measurement"]
    assert len(joints) == len(meas) == 2
    np.testing.assert_allclose(joints[0], q + 0.1)
    np.testing.assert_allclose(joints[1], q + 0.5)
    codes = [e.code for e in ctx.events if e.level == "warning"]
    assert codes == ["pose_unpaired", "pose_unpaired", "stale_reading"]
    assert "did not move now" in ctx.events[0].message and "before the pose was reached" in ctx.events[2].message
