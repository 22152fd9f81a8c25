"""``GuidanceResult``: what one run of the iterative guidance loop achieved (schema vgr.v1.GuidanceResult).

Carries the mode, the verdict (``converged`` | ``not_converged`` | ``refused`` | ``failed``), the
start and end TCP poses the docking formulas need (``T_start``, ``T_end``, T_base_tcp as the robot
reports them), the per-look residuals (what the matcher still saw, in mm and degrees) and each usable
look's ``T_match`` (so a report or a benchmark can redo the arithmetic of any look). The fields map
to the schema by name and type (engine.messages.mapping).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from engine.messages import Message
from engine.messages.schemas import define_proto

define_proto(
    "vgr/v1/guidance.proto",
    "vgr.v1",
    """
message GuidanceResult {             // one run of the guidance loop (plugins/actions/stages/guidance.py)
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;               // frame of the poses: the robot base
  string mode = 3;                   // eye_in_hand | eye_to_hand
  string verdict = 4;                // converged | not_converged | refused | failed
  repeated string reasons = 5;
  foxglove.Pose T_start = 6;
  foxglove.Pose T_end = 7;
  uint32 moves = 8;                  // corrective moves made
  repeated double residual_mm = 9;   // per look: |translation| of T_match
  repeated double residual_deg = 10; // per look: |rotation| of T_match
  repeated string match_verdicts = 11;
  uint64 job = 12;                   // sequence number of the trigger that started it
  repeated foxglove.Pose matches = 13; // per usable look: T_match (current -> template, camera frame)
  double translation_tol_mm = 14;    // the tolerances guidance converged against
  double rotation_tol_deg = 15;
}
""",
)

VERDICTS = ("converged", "not_converged", "refused", "failed")


@dataclass(kw_only=True, eq=False)
class GuidanceResult(Message, schema="vgr.v1.GuidanceResult"):
    """Outcome of one guidance run; only ``converged`` may be used for docking."""

    mode: str = "eye_in_hand"
    verdict: str = "failed"
    reasons: list[str] = field(default_factory=list)
    T_start: np.ndarray = field(default_factory=lambda: np.eye(4))
    T_end: np.ndarray = field(default_factory=lambda: np.eye(4))
    moves: int = 0
    residual_mm: list[float] = field(default_factory=list)
    residual_deg: list[float] = field(default_factory=list)
    match_verdicts: list[str] = field(default_factory=list)
    job: int = 0
    matches: list[np.ndarray] = field(default_factory=list)  # T_match per usable look
    translation_tol_mm: float = 0.0  # the tolerances guidance converged against (0: not stated)
    rotation_tol_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"guidance verdict {self.verdict!r} is not one of {VERDICTS}")

    @property
    def converged(self) -> bool:
        return self.verdict == "converged"
