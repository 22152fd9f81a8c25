"""``calibration_file``: publish a saved calibration result (a source), e.g. for ``vive_to_desktop``.

Reads a ``result.json`` written by ``vgr calibrate ... --json`` / ``--report`` or by a solver stage's
report (``CalibrationResult.to_dict``) and publishes it once as a CalibrationResultMsg, exactly as
the solver stage would have (transforms included only when the verdict is usable). A missing or
malformed file fails the stage at set-up, before any data flows.
"""

from __future__ import annotations

import json
from typing import ClassVar

from engine.messages import CalibrationResultMsg
from engine.stage import Stage, StageParams, input_file
from plugins.calibration.result import CalibrationResult
from plugins.calibration.stages.base import result_message


class CalibrationFile(Stage):
    """Publishes a saved CalibrationResult (result.json) once."""

    type_name = "calibration_file"
    role = "source"
    outputs: ClassVar = {"calibration": CalibrationResultMsg}

    class Params(StageParams):
        path: str = input_file(description="result.json of a calibration (relative: to the recipe file)")

    def setup(self) -> None:
        p: CalibrationFile.Params = self.params  # type: ignore[assignment]
        path = self.ctx.input_path(p.path)
        try:
            self.result = CalibrationResult.from_dict(json.loads(path.read_text()))
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"calibration file {path}: {exc}") from None

    def run(self) -> None:
        self.ctx.publish("calibration", result_message(self.result, self.ctx.clock.now_ns()))
