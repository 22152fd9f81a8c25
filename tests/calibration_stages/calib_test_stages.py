"""Stages used only by the calibration-stage tests (recipe ``plugins: [calib_test_stages]``).

``t_pose_pairs`` publishes hand-eye samples from a sample file: the robot poses on ``robot`` and
the camera observations on ``target``, stamped 1 s apart; ``skip_targets`` leaves some
observations out (missed detections) and ``target_stamp_offset_s`` shifts their stamps.
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field

from engine.hookspecs import hookimpl
from engine.messages import PoseStamped
from engine.stage import Stage, StageParams
from plugins.calibration.handeye.io import load_pose_pairs


class PosePairs(Stage):
    """Publishes the pose pairs of a hand-eye sample file."""

    type_name = "t_pose_pairs"
    role = "source"
    outputs: ClassVar = {"robot": PoseStamped, "target": PoseStamped}

    class Params(StageParams):
        path: str
        skip_targets: tuple[int, ...] = ()
        target_stamp_offset_s: float = 0.0
        limit: int = Field(0, ge=0, description="0 = all samples")

    def run(self) -> None:
        p: PosePairs.Params = self.params  # type: ignore[assignment]
        s = load_pose_pairs(p.path)
        n = len(s.T_base_tcp) if not p.limit else min(p.limit, len(s.T_base_tcp))
        for k in range(n):
            stamp = (k + 1) * 1_000_000_000
            self.ctx.publish("robot", PoseStamped(T=s.T_base_tcp[k], frame_id="base", stamp_ns=stamp))
            if k not in p.skip_targets:
                offset = round(p.target_stamp_offset_s * 1e9)
                self.ctx.publish("target", PoseStamped(T=s.T_cam_target[k], frame_id="camera", stamp_ns=stamp + offset))


@hookimpl
def vgr_stage_types() -> list[type]:
    return [PosePairs]
