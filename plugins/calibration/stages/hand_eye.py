"""``handeye_calibration``: hand-eye (AX=XB) or robot-world (AX=ZB) calibration as a solver stage.

Inputs: ``robot_pose`` (PoseStamped ``T_base_tcp`` as the robot reports it), ``target_pose``
(PoseStamped ``T_cam_target``: the calibration target / known object seen by the camera), ``solve``.
Samples are paired by stamp (see plugins.calibration.stages.base). Target poses that carry a covariance
(PoseWithCovarianceStamped, e.g. from ``board_pose``) set the camera noise model when none is declared:
each paired sample's own (``camera_covariances``; the solver estimates one common factor of them with
the robot's noise), or, when one of them is no covariance, the median of their variances per axis.
Publishes the result and, when usable, two transforms (of the set-up declared, or by default the one the data show: see
plugins.calibration.handeye.setup_choice): the hand-eye ``X`` (eye in hand: ``tcp -> camera_calibrated``; eye to hand:
``base -> camera_calibrated``) and the other unknown ``Y`` (``base -> target`` or ``tcp -> target``).
Frame names come from the messages (the robot poses' ``frame_id`` for the base, the target poses'
``frame_id`` for the camera, whose estimate is ``<camera>_calibrated`` unless ``camera_frame`` names it:
the camera stage publishes the camera's own frame with its mount); ``tcp_frame`` and ``target_frame``
name the others.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import PoseStamped, PoseWithCovarianceStamped
from plugins.calibration.handeye import NoiseModel, calibrate_hand_eye, calibrate_robot_world
from plugins.calibration.handeye.noise import camera_noise_from_covariances
from plugins.calibration.inputs import CalibrationInputError, hand_eye_samples
from plugins.calibration.result import CalibrationResult
from plugins.calibration.stages.base import CalibrationStage, PairingParams, calibrated


class HandEyeCalibration(CalibrationStage):
    """Hand-eye / robot-world calibration from robot poses and camera target poses (T_tcp_cam or T_base_cam)."""

    type_name = "handeye_calibration"
    KIND = "hand_eye"
    DATA_PORTS: ClassVar = {"robot_pose": PoseStamped, "target_pose": PoseStamped}

    class Params(PairingParams):
        setup: Literal["auto", "eye_in_hand", "eye_to_hand"] = Field(
            "auto", description="auto: the set-up the data show (Vuong's test; refused when they cannot tell)"
        )
        kind: Literal["hand_eye", "robot_world"] = Field("hand_eye", description="AX=XB or AX=ZB (Shah init)")
        robot_noise_deg_mm: tuple[float, float] | None = Field(None, description="declared robot noise (deg, mm)")
        camera_noise_deg_mm: tuple[float, float] | None = Field(
            None, description="declared camera noise (deg, mm); both unset: estimated from the data"
        )
        loss: Literal["huber", "cauchy", "linear"] = "huber"
        tcp_frame: str = "tcp"
        target_frame: str = "target"
        camera_frame: str | None = Field(None, description="the estimated camera frame (default: <camera>_calibrated)")

    def calibrate(self) -> tuple[CalibrationResult, list[str]]:
        p: HandEyeCalibration.Params = self.params  # type: ignore[assignment]
        samples, notes = hand_eye_samples(*self.streams(), **self.pairing())
        n = len(samples.T_base_tcp)
        if n < 3:
            raise CalibrationInputError(f"{n} pose pair(s): hand-eye calibration needs at least 3 (better 10-15)")
        noise, estimate, cov = None, None, None
        targets = self.buffers["target_pose"]
        if p.camera_noise_deg_mm is not None:
            r = p.robot_noise_deg_mm or (0.0, 0.0)
            noise = NoiseModel.isotropic(r[0], r[1], *p.camera_noise_deg_mm)
        elif p.robot_noise_deg_mm is not None:
            raise CalibrationInputError("camera_noise_deg_mm is needed when a noise model is declared")
        elif samples.camera_covariances is not None:
            cov, estimate = samples.camera_covariances, True
            self.ctx.event("info", "camera_noise", f"camera noise: each of the {n} paired target poses' own covariance "
                           "(one common factor of them estimated)")  # fmt: skip
        elif targets and all(isinstance(m, PoseWithCovarianceStamped) for m in targets):
            noise, estimate = camera_noise_from_covariances([m.covariance for m in targets]), True
            n = len(targets)
            self.ctx.event("info", "camera_noise", f"camera noise from the {n} target poses' covariances: "
                           f"{noise.camera.describe()} (1 sigma, median per axis)")  # fmt: skip
        solve = calibrate_robot_world if p.kind == "robot_world" else calibrate_hand_eye
        result = solve(
            samples.T_base_tcp, samples.T_cam_target, setup=p.setup, noise=noise, estimate_noise=estimate,
            loss=p.loss, seed=self.ctx.seed, camera_covariances=cov,
        )  # fmt: skip
        return result, notes

    def transforms(self, result: CalibrationResult) -> list[tuple[np.ndarray, str, str]]:
        p: HandEyeCalibration.Params = self.params  # type: ignore[assignment]
        base, cam = self.frame_of("robot_pose", "base"), self.frame_of("target_pose", "camera")
        cam = p.camera_frame or calibrated(cam)
        e = result.estimate
        if "T_tcp_cam" in e:  # eye in hand, declared or found from the data
            return [(e["T_tcp_cam"], p.tcp_frame, cam), (e["T_base_target"], base, p.target_frame)]
        return [(e["T_base_cam"], base, cam), (e["T_tcp_target"], p.tcp_frame, p.target_frame)]
