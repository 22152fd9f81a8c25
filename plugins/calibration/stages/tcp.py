"""``tcp_calibration``: TCP calibration with a fixed camera (seed 002) as a solver stage.

Inputs: ``robot_pose`` (PoseStamped ``T_base_flange``: the robot's reported pose of the frame the
TCP offset is calibrated in: the flange when the robot has no tool set, else its nominal TCP),
``point`` (PoseStamped whose translation is the TCP point seen by the camera, camera frame), and
``solve``. Publishes the result and, when usable, ``T_base_cam`` (robot frame_id ->
``<points' frame_id>_calibrated`` unless ``camera_frame`` names it: the camera's own frame is on the
tree already, under its stage's mount) and ``T_flange_tcp`` (``flange_frame`` -> ``tcp_frame``: the
calibrated TCP point with the flange's orientation; a point calibration does not determine the
tool's orientation). ``flange_frame`` is the frame the robot poses are of, ``tcp`` on the frames of
vgr's robot stages (their reported TCP: the flange when no tool is set).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import PoseStamped
from engine.transforms import T_from_Rt
from plugins.calibration.inputs import tcp_camera_data
from plugins.calibration.result import CalibrationResult
from plugins.calibration.stages.base import CalibrationStage, PairingParams, calibrated
from plugins.calibration.tcp_camera import TcpNoiseModel, calibrate_tcp_camera


class TcpCalibration(CalibrationStage):
    """TCP point on the flange (and T_base_cam) from flange poses and the TCP seen by a fixed camera."""

    type_name = "tcp_calibration"
    KIND = "tcp_camera"
    DATA_PORTS: ClassVar = {"robot_pose": PoseStamped, "point": PoseStamped}

    class Params(PairingParams):
        camera_sigma_m: tuple[float, float, float] = Field((3e-4, 3e-4, 3e-4), description="per camera axis")
        robot_position_sigma_m: float = Field(0.0, ge=0.0)
        robot_rotation_sigma_deg: float = Field(0.0, ge=0.0)
        loss: Literal["linear", "soft_l1", "huber", "cauchy"] = "linear"
        flange_frame: str = Field("tcp", description="the frame the robot poses are of (the robot's reported TCP)")
        tcp_frame: str = "tcp_calibrated"
        camera_frame: str | None = Field(None, description="the estimated camera frame (default: <camera>_calibrated)")

    def calibrate(self) -> tuple[CalibrationResult, list[str]]:
        p: TcpCalibration.Params = self.params  # type: ignore[assignment]
        noise = TcpNoiseModel(p.camera_sigma_m, p.robot_position_sigma_m, float(np.radians(p.robot_rotation_sigma_deg)))
        data, notes = tcp_camera_data(*self.streams(), noise=noise, **self.pairing())
        return calibrate_tcp_camera(data, loss=p.loss), notes

    def transforms(self, result: CalibrationResult) -> list[tuple[np.ndarray, str, str]]:
        p: TcpCalibration.Params = self.params  # type: ignore[assignment]
        base, cam = self.frame_of("robot_pose", "base"), p.camera_frame or calibrated(self.frame_of("point", "camera"))
        T_flange_tcp = T_from_Rt(np.eye(3), result.estimate["p_flange_tcp"])  # the point, flange orientation
        return [(result.estimate["T_base_cam"], base, cam), (T_flange_tcp, p.flange_frame, p.tcp_frame)]
