"""``kinematic_calibration``: kinematic (DH / MDH / POE) calibration as a solver stage (seed 003).

Inputs: ``joint_state`` (JointState: the joint angles the robot reports at each measurement),
``point`` (PoseStamped: the tool point measured by an external instrument, e.g. a laser tracker, in
its own frame; with ``measurement: pose`` also the measured tool orientation) and ``solve``.
The nominal model is ``model`` (a shipped name or a model file) with the nominal tool ``tool``;
the measurement frame and the tool point are estimated with the geometry.

Publishes the result (its JSON holds the calibrated model as a model-file mapping in
``estimate.model_file``, the identified parameter changes, the before/after figures) and, when
usable, ``T_meas_base`` (the instrument frame, from the measurements' frame_id -> ``base_frame``,
``base_calibrated``: the robot's own ``base`` already hangs under ``world``) and ``T_flange_tcp``
(``flange_frame`` -> ``tcp_frame``; name the robot's frame that is the flange: ``tcp`` for vgr's robot
stages with no tool set). After each solve it writes result.json, report.txt, summary.md,
convergence.png and before_after.txt in its folder of the run folder (or ``report_dir``:
engine/run_folder.py says where a named folder lies).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import JointState, PoseStamped
from plugins.calibration.inputs import CalibrationInputError, kinematic_samples, min_kinematic_samples
from plugins.calibration.kinematics import KinematicCalibration, KinematicCalibrationConfig, calibrate_kinematics
from plugins.calibration.report import format_result, kinematic_table, write_kinematic_files, write_report_dir
from plugins.calibration.result import CalibrationResult
from plugins.calibration.stages.base import CalibrationStage, PairingParams
from plugins.params import PoseSpec
from plugins.robot.model_file import load_robot_model


class KinematicCalibrationStage(CalibrationStage):
    """Kinematic (DH/MDH/POE) calibration from joint states and externally measured tool points."""

    type_name = "kinematic_calibration"
    KIND = "kinematic"
    DATA_PORTS: ClassVar = {"joint_state": JointState, "point": PoseStamped}

    class Params(PairingParams):
        model: str = Field("ur5e", description="nominal robot model: shipped name or model file")
        tool: PoseSpec | None = Field(None, description="nominal T_flange_tcp (default: the model's)")
        parameterisation: Literal["dh", "mdh", "poe"] | None = Field(None, description="default: the model's")
        measurement: Literal["position", "pose"] = "position"
        noise_position_m: float = Field(5e-5, gt=0.0, description="measurement noise per axis, 1 sigma")
        noise_rotation_deg: float = Field(float(np.degrees(1e-4)), gt=0.0)
        trust_noise: bool = Field(False, description="covariance from the stated noise, not the residuals")
        holdout_fraction: float = Field(0.25, ge=0.0, lt=1.0, description="share of samples held out for the table")
        max_iterations: int = Field(30, ge=1, le=1000)
        report_dir: str | None = Field(
            None, description="folder for the report files (default: the stage's folder in the run folder)"
        )
        base_frame: str = "base_calibrated"
        flange_frame: str = "flange"
        tcp_frame: str = "tcp_calibrated"

    def setup(self) -> None:
        super().setup()
        p: KinematicCalibrationStage.Params = self.params  # type: ignore[assignment]
        model = load_robot_model(p.model)
        self.model = model if p.tool is None else model.with_tool(p.tool.T())
        self.last: KinematicCalibration | None = None

    def calibrate(self) -> tuple[CalibrationResult, list[str]]:
        p: KinematicCalibrationStage.Params = self.params  # type: ignore[assignment]
        self.last = None
        samples, notes = kinematic_samples(*self.streams(), full_pose=p.measurement == "pose", **self.pairing())
        need = min_kinematic_samples(self.model.dof, samples.full_pose)
        if samples.n_samples < need:
            raise CalibrationInputError(
                f"{samples.n_samples} samples: a {self.model.dof}-joint calibration needs at least {need} "
                "(more equations than unknowns); 3-5x that is recommended"
            )
        config = KinematicCalibrationConfig(
            parameterisation=p.parameterisation,
            noise_position_m=p.noise_position_m,
            noise_rotation_rad=float(np.radians(p.noise_rotation_deg)),
            trust_noise=p.trust_noise,
            holdout_fraction=p.holdout_fraction,
            max_iterations=p.max_iterations,
        )
        self.last = calibrate_kinematics(self.model, samples, config=config)
        return self.last.result, notes

    def transforms(self, result: CalibrationResult) -> list[tuple[np.ndarray, str, str]]:
        p: KinematicCalibrationStage.Params = self.params  # type: ignore[assignment]
        meas = self.frame_of("point", "instrument")
        e = result.estimate
        return [(e["T_meas_base"], meas, p.base_frame), (e["T_flange_tcp"], p.flange_frame, p.tcp_frame)]

    def extra_outputs(self, result: CalibrationResult, stamp_ns: int) -> None:
        cal = self.last
        if cal is None:
            return
        m = result.metrics
        if "holdout_rms_after_mm" in m:
            self.ctx.event(
                "info",
                "kinematic_accuracy",
                f"held-out position RMS {m['holdout_rms_before_mm']:.3f} mm before, "
                f"{m['holdout_rms_after_mm']:.3f} mm after calibration",
                before_mm=m["holdout_rms_before_mm"],
                after_mm=m["holdout_rms_after_mm"],
            )
        p: KinematicCalibrationStage.Params = self.params  # type: ignore[assignment]
        folder = self.ctx.output_dir(p.report_dir)
        if folder is not None:
            text, sections = kinematic_table(cal)
            d = write_report_dir(folder, result, format_result(result) + "\n" + text, sections)
            write_kinematic_files(cal, d)
