"""``model_gap``: the model-gap workflow as a recipe stage (role solver).

Collects the robot's ``joint_state`` stream and the ``measurement`` stream (TrackerPose: the
measured tool point in the sensor frame), pairs them by stamp when both have ended
(:func:`.data.pair_streams`), runs the workflow and publishes the outcome on ``result`` (a
CalibrationResult message: kind ``model_gap``, verdict ``explained`` | ``explained_up_to_tie`` |
``unexplained`` | ``no_gap``, metrics in mm, the whole ``gap_report.json`` in ``result_json``). It
writes the report, the figures and the augmented model files in its folder of the run folder (or
``report_dir``: engine/run_folder.py says where a named folder lies). Bad or
insufficient data do not raise: the stage publishes verdict ``failed`` with the reason and an
``error``-free ``warning`` event.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

from pydantic import Field

from engine.messages import CalibrationResultMsg, JointState, TrackerPose
from engine.plain_data import plain
from engine.plugin_manager import PluginError
from engine.recipe.plugin_entries import resolve_plugin
from engine.stage import Stage, StageParams
from plugins.model_gap.analyse import analyse_gap
from plugins.model_gap.core import GapConfig, GapInputError, SelectionConfig
from plugins.model_gap.core.report import display, report_dict
from plugins.model_gap.data import GapDataError, with_payload
from plugins.model_gap.families import families_from_registry
from plugins.model_gap.recordings import pair_streams


class ModelGap(Stage):
    """Finds where the robot model and the measurements disagree and names the missing effect."""

    type_name = "model_gap"
    role = "solver"
    inputs: ClassVar = {"joint_state": JointState, "measurement": TrackerPose}
    outputs: ClassVar = {"result": CalibrationResultMsg}

    class Params(StageParams):
        model: str = Field("ur5e", description="shipped robot name, robot model file or augmented model file")
        noise_mm: float = Field(gt=0.0, description="measurement noise, 1 sigma per axis (mm)")
        calibrate: list[str] = Field(
            ["frame", "tool", "joints"],
            description="baseline calibration: frame, tool, joints (default: all, as far as the data identify them)",
        )
        report_dir: str | None = Field(
            None,
            description="folder for gap_report.json, figures and models (default: the stage's run folder)",
        )
        max_effects: int = Field(4, ge=0, le=20)
        alpha: float = Field(1e-3, gt=0.0, lt=0.5, description="family-wise false-positive rate per round")
        cv_folds: int = Field(5, ge=2, le=20)
        payload_kg: float | None = Field(None, ge=0.0, description="mass at the TCP during the campaign (kg)")
        effect_plugins: list[str] = Field(
            [],
            description="extra plugins (installed names or plugin files, as plugins:) whose vgr_model_effects "
            "join the catalog",
        )

    def __init__(self, ctx, params) -> None:  # buffers exist before setup: a device may publish from its setup
        super().__init__(ctx, params)
        self.joints: list[JointState] = []
        self.measurements: list[TrackerPose] = []

    def on_message(self, port: str, msg) -> None:  # type: ignore[override]
        (self.joints if port == "joint_state" else self.measurements).append(msg)

    def finish(self) -> None:
        p: ModelGap.Params = self.params  # type: ignore[assignment]
        sensor = self.measurements[0].frame_id if self.measurements else "sensor"
        try:
            data = pair_streams(self.joints, self.measurements)
            data.sensor, data.source = "tracker", f"stage {self.ctx.name} ({sensor} frame)"
            if p.payload_kg is not None:
                data = with_payload(data, p.payload_kg)
            cfg = GapConfig(
                SelectionConfig(alpha=p.alpha, cv_folds=p.cv_folds, seed=self.ctx.seed), max_effects=p.max_effects
            )
            # (plugin files relative to the recipe's folder, as its plugins: are)
            base = self.ctx.recipe_dir or Path.cwd()
            families = families_from_registry(tuple(resolve_plugin(e, base) for e in p.effect_plugins))
            result = analyse_gap(
                p.model,
                data,
                noise_mm=p.noise_mm,
                calibrate=None if list(p.calibrate) == ["frame", "tool", "joints"] else tuple(p.calibrate),
                report_dir=self.ctx.output_dir(p.report_dir),
                config=cfg,
                families=families,
            )
        except (GapDataError, GapInputError, PluginError, ValueError) as exc:
            self.ctx.event("warning", "model_gap_failed", str(exc))
            self.ctx.publish("result", CalibrationResultMsg(kind="model_gap", verdict="failed", reasons=[str(exc)]))
            return
        rep = report_dict(result)
        metrics = {k: float(rep[k]) for k in ("rms_before_mm", "rms_after_mm", "noise_floor_mm")}
        metrics["effects_added"] = float(len(rep["effects_added"]))
        metrics["tie_terms_added"] = float(sum(e["tied"] for e in rep["effects_added"]))
        folder = self.ctx.output_dir(p.report_dir)
        files = {"report": str(folder / "gap_report.json")} if folder is not None else {}
        self.ctx.event("result", "model_gap", gap_text(rep), verdict=result.verdict, files=files)
        self.ctx.publish(
            "result",
            CalibrationResultMsg(
                kind="model_gap",
                verdict=result.verdict,
                method="vgr gap: calibration + candidate effects, F-test/BIC/k-fold CV with a decisive margin",
                reasons=[result.reason],
                metrics=metrics,
                result_json=json.dumps(plain(rep, nan_as_none=True)),
            ),
        )


def gap_text(rep: dict) -> str:
    """The end-of-run answer: verdict, each effect added with its parameters and 1-sigma, the RMS."""
    parts = []
    for e in rep["effects_added"]:
        values = []
        for k, v in e["params"].items():
            shown, unit = display(v, e["units"].get(k, ""))  # the unit the CLI's table shows (urad, mm, ...)
            sd = display(e["param_std"].get(k, float("nan")), e["units"].get(k, ""))[0]
            values.append(f"{k} = {shown:.4g} ± {sd:.2g} {unit}".rstrip())
        parts.append(f"{e.get('label') or e['name'] + '@' + e['where']} ({', '.join(values)})")
    rms = f"RMS {rep['rms_before_mm']:.3f} -> {rep['rms_after_mm']:.3f} mm (noise {rep['noise_floor_mm']:.3f} mm)"
    return f"{rep['verdict']}: effects added: {'; '.join(parts) or 'none'}; {rms}"
