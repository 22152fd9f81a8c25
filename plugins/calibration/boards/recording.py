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

from collections.abc import Sequence
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

__all__ = ["DEFAULT_IMAGE_TOPICS", "RecordedViews", "paired_views", "recorded_views"]

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


def camera_at(infos: Sequence[CameraInfo], first_stamp: int) -> CameraModel:
    """The camera model stamped at or before *first_stamp* (the first image), else the first one."""
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
    if not images:
        raise CalibrationInputError(f"{path}: no images on {image_topic}")
    camera = None
    if camera_info_topic is not None:
        camera = camera_at(read_topic(rec, camera_info_topic, CameraInfo), images[0].stamp_ns)
    rv = paired_views(
        images, robot, board, pairing, names=(f"images on {image_topic}", f"robot poses on {robot_topic}")
    )
    rv.camera = camera
    return rv


def paired_views(
    images: Sequence[Image],
    robot: Sequence[PoseStamped],
    board: BoardSpec,
    pairing: PairingOptions | None = None,
    *,
    names: tuple[str, str] = ("images", "robot poses"),
) -> RecordedViews:
    """Each image paired with the robot pose of the nearest stamp (or in order: *pairing*), the board
    searched in each paired image; views where it was not found are listed and their poses dropped.
    A recording's messages (:func:`recorded_views`) or a stage's (``handeye_board_calibration``)."""
    p = pair_by_stamp_or_order(
        [m.stamp_ns for m in images], [m.stamp_ns for m in robot], names=names, **(pairing or {})
    )
    if not p.pairs:
        raise CalibrationInputError(f"no image could be paired with a robot pose ({names[0]}, {names[1]})")
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
        raise CalibrationInputError(f"images of different sizes ({names[0]}): {sorted(sizes)}")
    M = np.stack(poses) if poses else np.zeros((0, 4, 4))
    notes = [f"{len(p.pairs)} {names[0]} paired with {names[1]}", *p.notes]
    return RecordedViews(views, M, rejected, None, notes)
