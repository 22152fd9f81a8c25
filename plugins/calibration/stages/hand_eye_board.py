"""``handeye_board_calibration``: hand-eye (AX=XB) or robot-world (AX=ZB) calibration from the images
of a calibration board and the robot poses, as a solver stage.

It runs exactly what ``vgr calibrate handeye RUN.mcap --board SPEC`` runs on the recording of the same
messages (plugins.calibration.boards.recording.paired_views, then
plugins.calibration.boards.handeye_images.calibrate_handeye_images): the board found in each image,
the pose solver, then the maximum likelihood over the corners in pixels, with a covariance that
carries the robot's own pose noise estimated from the corners. A run and the command on its
recording give the same result, figure for figure (tests/calibration_stages/test_board_sim_recipe.py).

Inputs: ``robot_pose`` (PoseStamped ``T_base_tcp`` as the robot reports it), ``image`` (RawImage of
the board), ``camera_info`` (CameraInfo: the model the images were taken with, the one stamped at or
before the first image), ``solve``. Images pair with robot poses by stamp (see
plugins.calibration.stages.base); an image without the board drops its robot pose, with a note.

Why not ``board_pose`` -> ``handeye_calibration``: that chain takes each board pose's covariance as the
camera noise and has no model of the robot's own errors, and on the simulated cell of
``recipes/calibrate_handeye_board_sim.yaml`` (a UR5e with its joint errors) it reported a camera
position 2.7 sigma from the truth on every seed tried (0.24 mm off in z, sigma 0.09 mm), where
the images pipeline's 1 sigma (0.14 mm) holds it within 1.9 sigma (docs/calibration_boards.md).

Publishes the result and, when usable, the two transforms as ``handeye_calibration`` does (eye in
hand: ``tcp -> <camera>_calibrated`` and ``base -> target``; eye to hand: ``base -> <camera>_calibrated``
and ``tcp -> target``).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import CameraInfo, Image, PoseStamped
from plugins.calibration.boards.handeye_images import calibrate_handeye_images
from plugins.calibration.boards.recording import camera_at, paired_views
from plugins.calibration.inputs import CalibrationInputError
from plugins.calibration.result import CalibrationResult
from plugins.calibration.stages.base import CalibrationStage, PairingParams, calibrated
from plugins.calibration.stages.board_pose import BoardParams
from plugins.camera.board_spec import parse_board


class HandEyeBoardCalibration(CalibrationStage):
    """Hand-eye / robot-world calibration from board images and robot poses (T_tcp_cam or T_base_cam)."""

    type_name = "handeye_board_calibration"
    KIND = "hand_eye"
    DATA_PORTS: ClassVar = {"robot_pose": PoseStamped, "image": Image}
    SIDE_PORTS: ClassVar = {"camera_info": CameraInfo}

    class Params(PairingParams, BoardParams):
        setup: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand"
        kind: Literal["hand_eye", "robot_world"] = Field("hand_eye", description="AX=XB or AX=ZB")
        refine_intrinsics: bool = Field(False, description="refine the camera model with the poses")
        holdout: bool = Field(True, description="the leave-one-view-out reprojection figure (one fit per view)")
        tcp_frame: str = "tcp"
        target_frame: str = "target"
        camera_frame: str | None = Field(None, description="the estimated camera frame (default: <camera>_calibrated)")

    def calibrate(self) -> tuple[CalibrationResult, list[str]]:
        p: HandEyeBoardCalibration.Params = self.params  # type: ignore[assignment]
        images, robot = self.streams()
        if not images:
            raise CalibrationInputError("no images of the board arrived")
        infos = self.side["camera_info"]
        if not infos:
            raise CalibrationInputError("no camera model arrived on camera_info")
        rv = paired_views(images, robot, parse_board(p.board), self.pairing())
        out = calibrate_handeye_images(
            rv.views, rv.T_base_tcp, camera_at(infos, images[0].stamp_ns), kind=p.kind, setup=p.setup,
            refine_intrinsics=p.refine_intrinsics, rejected=rv.rejected, holdout=p.holdout,
        )  # fmt: skip
        notes = [*rv.notes[1:], *(f"{r.name}: {r.reason}; its robot pose is dropped" for r in rv.rejected)]
        return out.result, notes

    def streams(self) -> list[list]:
        return [self.buffers["image"], self.buffers["robot_pose"]]

    def transforms(self, result: CalibrationResult) -> list[tuple[np.ndarray, str, str]]:
        p: HandEyeBoardCalibration.Params = self.params  # type: ignore[assignment]
        base, cam = self.frame_of("robot_pose", "base"), self.frame_of("image", "camera")
        cam = p.camera_frame or calibrated(cam)
        e = result.estimate
        if "T_tcp_cam" in e:
            return [(e["T_tcp_cam"], p.tcp_frame, cam), (e["T_base_target"], base, p.target_frame)]
        return [(e["T_base_cam"], base, cam), (e["T_tcp_target"], p.tcp_frame, p.target_frame)]
