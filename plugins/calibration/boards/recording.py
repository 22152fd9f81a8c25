"""Board images, their camera model and the robot poses from a vgr recording, for hand-eye from images.

``vgr calibrate handeye|robot-world RUN.mcap --board SPEC`` reads three topics of a recording (the
defaults are those of ``recipes/calibrate_handeye_board_sim.yaml``):

* ``--image-topic`` (RawImage, grey or colour): the camera's images of the board;
* ``--camera-info-topic`` (CameraInfo): the camera model the images were taken with (the one stamped
  at or before the first image; ``--intrinsics FILE`` replaces it);
* ``--robot-topic`` (PoseStamped ``T_base_tcp``).

Each image is paired with the robot pose of the nearest stamp (``--pair``, ``--max-skew-s``,
``--drop-unmatched``: the options of every recording input, :mod:`plugins.calibration.inputs`);
the board is searched in every paired image (:func:`.detect.detect_board`), and images without it are
listed and their robot poses dropped, as for a folder of images. What follows is the images pipeline
(:func:`.handeye_images.calibrate_handeye_images`): the poses' and the corners' maximum likelihood.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from engine.messages import CameraInfo, Image, PoseStamped
from engine.recording.reader import load
from plugins.calibration.boards.detect import BoardNotFoundError, Detection, ImageReadError, Rejection, detect_board
from plugins.calibration.inputs import CalibrationInputError, PairingOptions, pair_by_stamp_or_order, read_topic
from plugins.camera.board_spec import BoardSpec
from plugins.camera.pinhole import CameraModel

__all__ = ["DEFAULT_IMAGE_TOPICS", "RecordedViews", "recorded_views"]

#: the sim camera's ports in recipes/calibrate_handeye_board_sim.yaml
DEFAULT_IMAGE_TOPICS = {"image": "/camera/image", "camera_info": "/camera/image_info"}


@dataclass
class RecordedViews:
    """The views where the board was found, their robot poses ``T_base_tcp`` ``(n, 4, 4)``, the images
    where it was not, the recording's camera model (None without the topic) and notes on the input."""

    views: list[Detection]
    T_base_tcp: NDArray[np.float64]
    rejected: list[Rejection]
    camera: CameraModel | None
    notes: list[str] = field(default_factory=list)


def _camera(infos: list[CameraInfo], first_stamp: int) -> CameraModel:
    before = [i for i in infos if i.stamp_ns <= first_stamp]
    return CameraModel.from_camera_info(before[-1] if before else infos[0])


def recorded_views(
    path: str | Path,
    board: BoardSpec,
    *,
    image_topic: str = DEFAULT_IMAGE_TOPICS["image"],
    camera_info_topic: str | None = DEFAULT_IMAGE_TOPICS["camera_info"],
    robot_topic: str = "/poses/tcp_pose",
    pairing: PairingOptions | None = None,
) -> RecordedViews:
    """The board's views and robot poses of a recording (module docstring); ``camera_info_topic=None``
    reads no camera model (the caller has one)."""
    rec = load(path)
    images = read_topic(rec, image_topic, Image)
    robot = read_topic(rec, robot_topic, PoseStamped)
    camera = None
    if camera_info_topic is not None:
        camera = _camera(read_topic(rec, camera_info_topic, CameraInfo), images[0].stamp_ns)
    p = pair_by_stamp_or_order(
        [m.stamp_ns for m in images], [m.stamp_ns for m in robot], names=("images", "robot poses"), **(pairing or {})
    )
    if not p.pairs:
        raise CalibrationInputError(f"{path}: no image could be paired with a robot pose")
    views: list[Detection] = []
    poses: list[NDArray[np.float64]] = []
    rejected: list[Rejection] = []
    for i, j in p.pairs:
        name = f"image t={images[i].stamp_ns / 1e9:.3f}s"
        try:
            views.append(detect_board(images[i].data, board, name))
        except (BoardNotFoundError, ImageReadError) as exc:
            rejected.append(Rejection(name, str(exc)))
            continue
        poses.append(np.asarray(robot[j].T, dtype=float))
    sizes = {v.image_size for v in views}
    if len(sizes) > 1:
        raise CalibrationInputError(f"{path}: images of different sizes on {image_topic}: {sorted(sizes)}")
    M = np.stack(poses) if poses else np.zeros((0, 4, 4))
    notes = [f"{len(p.pairs)} image(s) on {image_topic} paired with robot poses on {robot_topic}", *p.notes]
    return RecordedViews(views, M, rejected, camera, notes)
