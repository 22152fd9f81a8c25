"""The ``MatchResult`` message: a matcher's answer on the bus (schema ``vgr.v1.MatchResult``).

Carries the verdict, ``T_match`` (current -> template, see plugins.registration.result)
when the verdict is ``ok``, the quality figures, the per-axis one-sigma uncertainty, and the full
:class:`RegistrationResult` as JSON. Registered through the ``vgr_message_types`` hook, like any
plugin's message type; its fields map to the schema by name and type (engine.messages.mapping).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from engine.messages import Message, Wire, WireMap
from engine.messages.schemas import define_proto
from plugins.registration.result import RegistrationResult

define_proto(
    "vgr/v1/registration.proto",
    "vgr.v1",
    """
message MatchResult {                // a point-cloud matcher's answer (plugins/registration)
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
class MatchResult(Message, schema="vgr.v1.MatchResult"):
    """A matcher's verdict and ``T_match`` (None unless the verdict is ok)."""

    WIRE: ClassVar[WireMap] = {"T_match": Wire(presence="has_match")}

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
