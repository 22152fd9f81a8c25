"""The ``MatchResult`` message: a matcher's answer on the bus (schema ``vgr.v1.MatchResult``).

Carries the verdict, ``T_match`` (current -> template, see plugins.solvers.registration.result)
when the verdict is ``ok``, the quality figures, the per-axis one-sigma uncertainty, and the full
:class:`RegistrationResult` as JSON. Registered through the ``vgr_message_types`` hook, like any
plugin's message type.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

import numpy as np

from engine.messages import Bulk, Message, get_pose, get_stamp, set_pose, set_stamp
from engine.schemas import ProtoMessage, define_proto

from .result import RegistrationResult

define_proto(
    "vgr/v1/registration.proto",
    "vgr.v1",
    """
message MatchResult {                // a point-cloud matcher's answer (plugins/solvers/registration)
  google.protobuf.Timestamp timestamp = 1;
  string frame_id = 2;               // the template camera frame
  string method = 3;
  string verdict = 4;                // ok | ambiguous | failed
  repeated string reasons = 5;
  bool has_match = 6;
  foxglove.Pose T_match = 7;         // maps current points onto the template (only when has_match)
  double fitness = 8;
  double inlier_rmse_m = 9;
  repeated double sigma = 10;        // 1-sigma x, y, z (m), rx, ry, rz (rad) at the part centre
  double score_gap = 11;
  string result_json = 12;           // the complete RegistrationResult
}
""",
)


@dataclass(kw_only=True, eq=False)
class MatchResult(Message):
    """A matcher's verdict and ``T_match`` (None unless the verdict is ok)."""

    TYPE: ClassVar[str] = "MatchResult"
    SCHEMA: ClassVar[str] = "vgr.v1.MatchResult"

    method: str = ""
    verdict: str = "failed"
    reasons: list[str] = field(default_factory=list)
    T_match: np.ndarray | None = None
    fitness: float = 0.0
    inlier_rmse_m: float = float("nan")
    sigma: np.ndarray | None = None
    score_gap: float = float("nan")
    result_json: str = ""

    @classmethod
    def from_result(cls, res: RegistrationResult, frame_id: str = "camera") -> MatchResult:
        sigma = None
        if res.sigma_translation_m is not None and res.sigma_rotation_rad is not None:
            sigma = np.concatenate([res.sigma_translation_m, res.sigma_rotation_rad])
        return cls(
            frame_id=frame_id,
            method=res.method,
            verdict=res.verdict,
            reasons=list(res.reasons),
            T_match=None if res.T_match is None or res.verdict != "ok" else np.asarray(res.T_match, dtype=float),
            fitness=float(res.fitness),
            inlier_rmse_m=float(res.inlier_rmse),
            sigma=sigma,
            score_gap=float(res.score_gap),
            result_json=res.to_json(),
        )

    @property
    def usable(self) -> bool:
        return self.verdict == "ok" and self.T_match is not None

    def details(self) -> dict[str, Any]:
        return json.loads(self.result_json) if self.result_json else {}

    def to_proto(self) -> tuple[ProtoMessage, Bulk]:
        pb = self.proto()
        set_stamp(pb, self.stamp_ns)
        pb.frame_id, pb.method, pb.verdict, pb.result_json = self.frame_id, self.method, self.verdict, self.result_json
        pb.reasons.extend(self.reasons)
        pb.has_match = self.T_match is not None
        if self.T_match is not None:
            set_pose(pb.T_match, self.T_match)
        pb.fitness, pb.inlier_rmse_m, pb.score_gap = self.fitness, self.inlier_rmse_m, self.score_gap
        if self.sigma is not None:
            pb.sigma.extend(np.asarray(self.sigma, dtype=float).tolist())
        return pb, None

    @classmethod
    def from_proto(cls, pb: Any, bulk: Bulk) -> Self:
        return cls(
            stamp_ns=get_stamp(pb),
            frame_id=pb.frame_id,
            method=pb.method,
            verdict=pb.verdict,
            reasons=list(pb.reasons),
            T_match=get_pose(pb.T_match) if pb.has_match else None,
            fitness=pb.fitness,
            inlier_rmse_m=pb.inlier_rmse_m,
            sigma=np.array(pb.sigma) if len(pb.sigma) else None,
            score_gap=pb.score_gap,
            result_json=pb.result_json,
        )
