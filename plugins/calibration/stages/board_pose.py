"""``board_pose``: the pose of a calibration board in each camera image, with its covariance.

The camera observation of hand-eye calibration with a board (docs/calibration_boards.md): each image
(input ``image``, a RawImage: ``mono8``, ``rgb8``/``bgr8`` or 16-bit grey) is searched for the board
``board`` (a spec string such as ``chessboard:9x6:25mm`` or a board file,
:mod:`plugins.camera.board_spec`) by :func:`plugins.calibration.boards.detect.detect_board`, and the
board library's :func:`plugins.calibration.boards.board_pose.board_pose` gives ``T_cam_target`` with its
6x6 covariance (from the reprojection Jacobian and the corner noise: ``sigma_px`` when given, else
estimated from the view's own residuals). The camera model comes from input ``camera_info``
(CameraInfo: K, distortion D and its model, as the camera publishes it beside its images).

Pairing: an image is handled with the newest camera model stamped at or before it, once a camera
model stamped at or after it has arrived (a camera publishes its model with each image, in either
order) or, at the end of input, with the newest one at all. The engine orders messages within a port,
not across ports, and replay delivers them in the recorded order, so a run and its replay pair alike.

Output ``pose``: :class:`PoseWithCovarianceStamped` ``T_cam_target`` in the image's frame, stamped
like the image (``handeye_calibration`` pairs it with the robot pose of the same stamp and takes the
camera noise from the covariances). An image where the board is not found, or whose pose is refused
(an ambiguous board, the camera behind the board, an image of another size than the camera model's),
raises a ``warning`` event saying why and publishes nothing: the calibration then drops that robot
pose. At the end an ``info`` event counts the views and gives their reprojection RMS.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field, field_validator

from engine.messages import CameraInfo, Image, PoseWithCovarianceStamped
from engine.stage import Stage, StageParams
from plugins.calibration.boards.board_pose import board_pose
from plugins.calibration.boards.detect import BoardNotFoundError, ImageReadError, detect_board
from plugins.camera.board_spec import BoardSpec, parse_board
from plugins.camera.pinhole import CameraModel


class BoardParams(StageParams):
    """The ``board`` parameter of the stages that look for a board, checked when the recipe loads."""

    board: str = Field(description="board spec (e.g. chessboard:9x6:25mm, charuco:...) or a board file")

    @field_validator("board")
    @classmethod
    def _parses(cls, v: str) -> str:
        parse_board(v)  # a BoardSpecError (a ValueError) names what is wrong
        return v


class BoardPose(Stage):
    """Pose of a calibration board in each image (T_cam_target with its 6x6 covariance)."""

    type_name = "board_pose"
    role = "solver"
    inputs: ClassVar = {"image": Image, "camera_info": CameraInfo}
    outputs: ClassVar = {"pose": PoseWithCovarianceStamped}

    class Params(BoardParams):
        sigma_px: float | None = Field(
            None, gt=0.0, description="corner noise per pixel coordinate; None: from each view's residuals"
        )
        allow_ambiguous: bool = Field(False, description="accept a board whose origin the image cannot tell")

    def setup(self) -> None:
        p: BoardPose.Params = self.params  # type: ignore[assignment]
        self.board: BoardSpec = parse_board(p.board)
        self.images: list[Image] = []
        self.infos: list[CameraInfo] = []
        self.rms_px: list[float] = []
        self.refused = 0

    def on_message(self, port: str, msg: Image | CameraInfo) -> None:  # type: ignore[override]
        if port == "camera_info":
            self.infos.append(msg)  # type: ignore[arg-type]
        else:
            self.images.append(msg)  # type: ignore[arg-type]
        self._handle_ready(final=False)

    def finish(self) -> None:
        self._handle_ready(final=True)
        n = len(self.rms_px) + self.refused
        if n:
            rms = f"; reprojection RMS median {np.median(self.rms_px):.3f} px" if self.rms_px else ""
            self.ctx.event(
                "info",
                "board_poses",
                f"board found in {len(self.rms_px)} of {n} image(s) ({self.board.describe()}){rms}",
                found=len(self.rms_px),
                images=n,
            )

    def _info_for(self, image: Image, final: bool) -> CameraInfo | None:
        """The camera model of *image* (module docstring), or None while it may still come."""
        if not self.infos:
            return None
        if not final and not any(i.stamp_ns >= image.stamp_ns for i in self.infos):
            return None
        before = [i for i in self.infos if i.stamp_ns <= image.stamp_ns]
        return before[-1] if before else self.infos[0]

    def _handle_ready(self, final: bool) -> None:
        while self.images:
            info = self._info_for(self.images[0], final)
            if info is None:
                if final:
                    self.ctx.event("warning", "no_camera_info", f"{len(self.images)} image(s) without a camera model")
                    self.refused += len(self.images)
                    self.images.clear()
                return
            self._handle(self.images.pop(0), info)

    def _handle(self, image: Image, info: CameraInfo) -> None:
        p: BoardPose.Params = self.params  # type: ignore[assignment]
        name = f"image t={image.stamp_ns / 1e9:.3f}s"
        try:
            camera = CameraModel.from_camera_info(info)
            detection = detect_board(image.data, self.board, name)
            pose = board_pose(detection, camera, sigma_px=p.sigma_px, allow_ambiguous=p.allow_ambiguous)
        except (BoardNotFoundError, ImageReadError, ValueError) as exc:  # AmbiguousBoardError is a ValueError
            self.refused += 1
            code = "board_not_found" if isinstance(exc, BoardNotFoundError) else "board_pose_refused"
            why = str(exc) if str(exc).startswith(name) else f"{name}: {exc}"
            self.ctx.event("warning", code, f"{why}; no board pose", stamp_ns=image.stamp_ns)
            return
        self.rms_px.append(pose.rms_px)
        self.ctx.publish(
            "pose",
            PoseWithCovarianceStamped(
                T=pose.T_cam_target,
                covariance=pose.covariance,
                frame_id=image.frame_id or info.frame_id,
                stamp_ns=image.stamp_ns,
            ),
        )
