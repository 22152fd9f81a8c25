"""One robot move through the ``robot`` service client, for action stages (guidance, docking).

``move`` sends a ``RobotCommand`` with an idempotent command id and returns the reply, or raises
``MoveRefused`` with an alarm code: ``robot_unavailable`` (no answer, service error),
``robot_refused`` (the controller said no, or gave no pose back) or ``duplicate_command`` (the
controller had already handled this id — a retry, or an earlier run with the same ids and the same
command journal — so nothing moved now, and the pose in the reply is an old one). Callers turn it
into their alarm.
"""

from __future__ import annotations

import numpy as np

from engine.messages import RobotCommand, RobotReply
from engine.stage import ServiceError, StageContext


class MoveRefused(Exception):  # noqa: N818 - a refusal, not a program error
    """The move did not happen; ``code`` is the alarm code."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


def move(
    ctx: StageContext, command_id: str, T: np.ndarray, kind: str, *, speed: float = 0.0, timeout_s: float = 30.0
) -> RobotReply:
    """Move to ``T`` (T_base_tcp) with ``kind`` (move_l | move_j); the controller's reply."""
    cmd = RobotCommand(command_id=command_id, kind=kind, T=T, speed=speed, frame_id="base")
    try:
        reply = ctx.call("robot", cmd, timeout_s=timeout_s)
    except ServiceError as exc:
        raise MoveRefused("robot_unavailable", str(exc)) from None
    if reply.duplicate:
        raise MoveRefused(
            "duplicate_command",
            f"the robot had already handled command {command_id} and did not move now (a retry, or an earlier "
            "run: command ids restart with every run, so a command journal kept across runs must be cleared "
            "or be one file per run)",
        )
    if not reply.ok or reply.T is None:
        raise MoveRefused("robot_refused", f"move {command_id} refused: {reply.error or 'no pose in the reply'}")
    return reply
