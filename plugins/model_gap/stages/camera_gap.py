"""``camera_gap``: the camera model-gap workflow as a recipe stage (role solver).

Collects the ``image`` stream (RawImage of a calibration board: ``mono8``, ``rgb8`` / ``bgr8`` or
16-bit grey), finds the board in each image as it arrives (plugins.calibration.boards.detect), and
when the stream has ended runs what ``vgr gap --camera IMAGES --board SPEC`` runs on the same images
(plugins.model_gap.camera.workflow): the baseline camera against the detected corners on held-out
views, the catalog effect named (or a tie term), the verdict. Publishes a CalibrationResult on
``result`` (kind ``camera_gap``, verdict ``explained`` | ``explained_up_to_tie`` | ``unexplained`` |
``no_gap``, metrics in px, the ``vgr.camera_gap_report/1`` document in ``result_json``) and writes
``camera_gap_report.json`` in its folder of the run folder (or ``report_dir``). Too few views or a
failed fit do not raise: the verdict is ``failed`` with the reason and a ``warning`` event.
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field, field_validator

from engine.messages import CalibrationResultMsg, Image
from engine.stage import Stage, StageParams
from plugins.calibration.boards.detect import BoardNotFoundError, Detection, ImageReadError, detect_board
from plugins.camera.board_spec import parse_board
from plugins.model_gap.camera.report import report_dict
from plugins.model_gap.camera.workflow import CameraGapConfig, run_camera_gap
from plugins.model_gap.stages.gap_stage_result import publish_failed, publish_verdict, write_report


class CameraGap(Stage):
    """Compares the camera model with the board corners in the images and names the missing lens effect."""

    type_name = "camera_gap"
    role = "solver"
    inputs: ClassVar = {"image": Image}
    outputs: ClassVar = {"result": CalibrationResultMsg}

    class Params(StageParams):
        board: str = Field(description="board spec (chessboard:25x18:15mm, charuco:..., circles:...) or board file")
        alpha: float = Field(1e-3, gt=0.0, lt=0.5, description="family-wise false-positive rate per round")
        folds: int = Field(5, ge=2, le=20, description="cross-validation folds over the views")
        max_effects: int = Field(4, ge=0, le=6, description="at most this many terms are added (4, as vgr gap)")
        report_dir: str | None = Field(None, description="folder for camera_gap_report.json (default: the stage's)")

        @field_validator("board")
        @classmethod
        def _parses(cls, v: str) -> str:
            parse_board(v)  # BoardSpecError (a ValueError) names what is wrong
            return v

    def __init__(self, ctx, params) -> None:  # buffers exist before setup: a device may publish from its setup
        super().__init__(ctx, params)
        self.views: list[Detection] = []
        self.refused = 0

    def on_message(self, port: str, msg: Image) -> None:  # type: ignore[override]
        p: CameraGap.Params = self.params  # type: ignore[assignment]
        name = f"image t={msg.stamp_ns / 1e9:.3f}s"
        try:
            view = detect_board(msg.data, parse_board(p.board), name)
        except (BoardNotFoundError, ImageReadError) as exc:
            self.refused += 1
            self.ctx.event("warning", "board_not_found", f"{name}: {exc}", stamp_ns=msg.stamp_ns)
            return
        if self.views and view.image_size != self.views[0].image_size:
            self.refused += 1
            self.ctx.event("warning", "image_size", f"{name}: image size {view.image_size} differs; left out")
            return
        self.views.append(view)

    def finish(self) -> None:
        p: CameraGap.Params = self.params  # type: ignore[assignment]
        cfg = CameraGapConfig(alpha=p.alpha, folds=p.folds, seed=self.ctx.seed, max_effects=p.max_effects)
        try:
            if not self.views:
                raise ValueError(f"the board was found in none of the {self.refused} image(s)")
            result = run_camera_gap(self.views, self.views[0].image_size, cfg)
        except Exception as exc:  # too few views, an OpenCV fit refusing: a failed result, not a failed run
            publish_failed(self.ctx, "camera_gap", exc)
            return
        doc = report_dict(result, board=parse_board(p.board).spec)
        files = write_report(self.ctx, p.report_dir, "camera_gap_report.json", doc)
        metrics = {k: float(doc[k]) for k in ("heldout_rms_before_px", "heldout_rms_after_px", "rms_after_px")}
        metrics["effects_added"] = float(len(doc["effects_added"]))
        metrics["n_views"] = float(doc["n_views"])
        added = ", ".join(e["name"] for e in doc["effects_added"]) or "none"
        text = (
            f"{result.verdict}: added {added}; held-out RMS {metrics['heldout_rms_before_px']:.4f} -> "
            f"{metrics['heldout_rms_after_px']:.4f} px over {len(self.views)} views"
        )
        publish_verdict(
            self.ctx, "camera_gap", result, doc, text=text, metrics=metrics, files=files,
            method="vgr gap --camera: OpenCV calibrateCamera per catalog effect, Wilcoxon over held-out views",
        )  # fmt: skip
