"""``calibration_evaluator``: how far a calibration landed from the simulation's truth (a sink).

The recipe names the truth it set up (the camera mount it gave the simulated camera, the tip it gave
the simulated tool), best through the same ``vars`` entry the simulated stage reads, and wires the
solver's ``result`` here; at the end of the run the evaluator reports, for each named estimate, its
error in mm and degrees (event ``calibration_evaluation``, details ``errors``: per estimate
``error_mm`` and, for transforms, ``error_deg``), and the result's own 1-sigma where it has one, so
the stated uncertainty can be judged against the truth. A solver never sees these numbers: the
evaluator is a sink.
"""

from __future__ import annotations

import json
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.messages import CalibrationResultMsg
from engine.stage import Stage, StageParams
from engine.transforms import pose_error
from plugins.calibration.result import CalibrationResult
from plugins.params import PoseSpec


class CalibrationEvaluator(Stage):
    """Error of a calibration's estimates against the simulated truth: mm and degrees."""

    type_name = "calibration_evaluator"
    role = "sink"
    inputs: ClassVar = {"calibration": CalibrationResultMsg}

    class Params(StageParams):
        truth: dict[str, PoseSpec] = Field(
            default_factory=dict, description="true transforms by estimate name, e.g. T_tcp_cam, T_base_cam"
        )
        truth_points_m: dict[str, tuple[float, float, float]] = Field(
            default_factory=dict, description="true points by estimate name (m), e.g. p_flange_tcp"
        )

    def setup(self) -> None:
        self.last: CalibrationResultMsg | None = None

    def on_message(self, port: str, msg: CalibrationResultMsg) -> None:  # type: ignore[override]
        self.last = msg

    def finish(self) -> None:
        if self.last is None:
            self.ctx.event("warning", "calibration_evaluation", "no calibration result arrived: nothing to evaluate")
            return
        result = CalibrationResult.from_dict(json.loads(self.last.result_json))
        errors = self.errors(result)
        parts = [
            f"{name} {e['error_mm']:.3f} mm" + (f" / {e['error_deg']:.4f} deg" if "error_deg" in e else "")
            if "error_mm" in e
            else f"{name}: {e['missing']}"
            for name, e in errors.items()
        ]
        text = f"truth ({result.kind}, verdict {result.verdict}): " + ("; ".join(parts) or "no truth named")
        self.ctx.event("result", "calibration_evaluation", text, verdict=result.verdict, errors=errors)

    def errors(self, result: CalibrationResult) -> dict[str, dict[str, Any]]:
        """Per named estimate: its error against the truth (or why there is none)."""
        p: CalibrationEvaluator.Params = self.params  # type: ignore[assignment]
        out: dict[str, dict[str, Any]] = {}
        for name, spec in p.truth.items():
            est = result.estimate.get(name)
            if not (isinstance(est, np.ndarray) and est.shape == (4, 4)):
                out[name] = {"missing": "not a transform of this result"}
                continue
            t, r = pose_error(spec.T(), est)
            out[name] = {"error_mm": t * 1e3, "error_deg": float(np.degrees(r))}
        for name, point in p.truth_points_m.items():
            est = result.estimate.get(name)
            if est is None or np.asarray(est).shape != (3,):
                out[name] = {"missing": "not a point of this result"}
                continue
            out[name] = {"error_mm": float(np.linalg.norm(np.asarray(est, float) - point)) * 1e3}
        return out
