"""``depth_gap``: the depth camera's model-gap workflow as a recipe stage (role solver).

Collects the ``depth`` stream (Image ``32FC1``, metres, NaN where invalid), the camera's intrinsics
(``camera_info``: the newest one counts) and the target's pose per depth image (``target_pose``: a
PoseStamped ``T_cam_target`` stamped like its depth image, e.g. ``board_pose.pose`` from the
registered IR or colour image; the target is its frame's ``z = 0`` plane, optionally limited to
``target_extent_m``). When the streams have ended it runs what ``vgr gap --depth CAPTURES`` runs
(plugins.model_gap.depth.workflow): the baseline range against the measured one on held-out
captures, the catalog effect named (or a tie term), the verdict. ``target: fit`` fits the plane per
capture instead and reads no pose (the port must still be wired); ``auto`` (the default) is
``known`` when any pose arrived (a depth image without one is then left out with a warning: the
board was not found in its image) and ``fit`` when none did. Publishes a CalibrationResult on ``result`` (kind
``depth_gap``, verdict ``explained`` | ``explained_up_to_tie`` | ``unexplained`` | ``no_gap``, metrics
in mm, the ``vgr.depth_gap_report/1`` document in ``result_json``) and writes
``depth_gap_report.json`` in its folder of the run folder (or ``report_dir``). Too few captures or
refused input do not raise: the verdict is ``failed`` with the reason and a ``warning`` event.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import CalibrationResultMsg, CameraInfo, Image, PoseStamped
from engine.stage import Stage, StageParams
from plugins.model_gap.depth.data import DepthCaptures, DepthFrame, SigmaLaw
from plugins.model_gap.depth.report import report_dict
from plugins.model_gap.depth.workflow import DepthGapConfig, run_depth_gap
from plugins.model_gap.stages.gap_stage_result import publish_failed, publish_verdict, write_report


class DepthGap(Stage):
    """Compares a depth camera's ranges with a known flat target and names the missing range effect."""

    type_name = "depth_gap"
    role = "solver"
    inputs: ClassVar = {"depth": Image, "camera_info": CameraInfo, "target_pose": PoseStamped}
    outputs: ClassVar = {"result": CalibrationResultMsg}

    class Params(StageParams):
        target: Literal["auto", "known", "fit"] = Field("auto", description="the target's pose known, or fitted")
        target_extent_m: tuple[float, float, float, float] | None = Field(
            None, description="x_min, x_max, y_min, y_max of the target in its frame (default: its whole plane)"
        )
        noise_mm: float | None = Field(None, ge=0.0, description="stated range noise sigma(z) = noise_mm + ...")
        noise_mm_per_m2: float | None = Field(None, ge=0.0, description="... + noise_mm_per_m2 * z^2 (z in m)")
        alpha: float = Field(1e-3, gt=0.0, lt=0.5, description="family-wise false-positive rate per round")
        folds: int = Field(5, ge=2, le=20, description="cross-validation folds over the captures")
        max_effects: int = Field(4, ge=0, le=6, description="at most this many terms are added (4, as vgr gap)")
        outlier_alpha: float = Field(0.01, ge=0.0, lt=0.5, description="gross-error screen (0: none)")
        report_dir: str | None = Field(None, description="folder for depth_gap_report.json (default: the stage's)")

    def __init__(self, ctx, params) -> None:  # buffers exist before setup: a device may publish from its setup
        super().__init__(ctx, params)
        self.depths: list[Image] = []
        self.poses: dict[int, np.ndarray] = {}
        self.info: CameraInfo | None = None

    def on_message(self, port: str, msg) -> None:  # type: ignore[override]
        if port == "depth":
            if msg.encoding != "32FC1":
                self.ctx.event("warning", "depth_encoding", f"depth image t={msg.stamp_ns}: {msg.encoding}, not 32FC1")
                return
            self.depths.append(msg)
        elif port == "camera_info":
            self.info = msg
        elif port == "target_pose":
            self.poses[int(msg.stamp_ns)] = np.asarray(msg.T, float)

    def _mode(self) -> str:
        p: DepthGap.Params = self.params  # type: ignore[assignment]
        if p.target == "auto":
            return "known" if self.poses else "fit"
        return p.target

    def _captures(self) -> DepthCaptures:
        """The depth images paired with their poses by stamp (ValueError: nothing usable)."""
        p: DepthGap.Params = self.params  # type: ignore[assignment]
        mode = self._mode()
        if self.info is None:
            raise ValueError("no camera_info arrived: the depth images' intrinsics are unknown")
        if not self.depths:
            raise ValueError("no depth image arrived")
        size = (int(self.info.width), int(self.info.height))
        frames = []
        for im in self.depths:
            name = f"depth t={im.stamp_ns / 1e9:.3f}s"
            if im.data.shape != (size[1], size[0]):
                self.ctx.event("warning", "image_size", f"{name}: shape {im.data.shape}, camera {size}; left out")
                continue
            T = None if mode == "fit" else self.poses.get(int(im.stamp_ns))
            if T is None and mode == "known":
                self.ctx.event("warning", "no_target_pose", f"{name}: no target pose with its stamp; left out")
                continue
            frames.append(DepthFrame(name, np.asarray(im.data, float), T, p.target_extent_m))
        sigma = None
        if p.noise_mm is not None or p.noise_mm_per_m2 is not None:
            sigma = SigmaLaw((p.noise_mm or 0.0) / 1e3, (p.noise_mm_per_m2 or 0.0) / 1e3)
        D = np.asarray(self.info.D, float) if len(self.info.D) else None
        return DepthCaptures(frames, np.asarray(self.info.K, float), size, D, sigma, "depth_gap stage")

    def finish(self) -> None:
        p: DepthGap.Params = self.params  # type: ignore[assignment]
        cfg = DepthGapConfig(
            alpha=p.alpha, folds=p.folds, seed=self.ctx.seed, max_effects=p.max_effects, target=self._mode(),
            outlier_alpha=p.outlier_alpha,
        )  # fmt: skip
        try:
            captures = self._captures()
            result = run_depth_gap(captures, cfg)
        except Exception as exc:  # too few captures, refused input: a failed result, not a failed run
            publish_failed(self.ctx, "depth_gap", exc)
            return
        rejected = [{"name": name, "reason": why} for name, why in captures.rejected]
        doc = report_dict(result, rejected, "depth_gap stage")
        files = write_report(self.ctx, p.report_dir, "depth_gap_report.json", doc)
        metrics = {k: float(doc[k]) for k in ("heldout_rms_before_mm", "heldout_rms_after_mm", "rms_after_mm")}
        metrics["effects_added"] = float(len(doc["effects_added"]))
        metrics["n_captures"] = float(doc["n_captures"])
        metrics["n_flagged"] = float(doc["gross_errors"]["n_flagged"])
        added = ", ".join(e["name"] for e in doc["effects_added"] if not e["dropped"]) or "none"
        text = (
            f"{result.verdict}: added {added}; held-out range RMS {metrics['heldout_rms_before_mm']:.4f} -> "
            f"{metrics['heldout_rms_after_mm']:.4f} mm over {doc['n_captures']} captures"
        )
        publish_verdict(
            self.ctx, "depth_gap", result, doc, text=text, metrics=metrics, files=files,
            method="vgr gap --depth: linear range-error effects, Wilcoxon over held-out captures",
        )  # fmt: skip
