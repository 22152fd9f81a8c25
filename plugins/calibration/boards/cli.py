"""``vgr calibrate intrinsics IMAGES... --board SPEC`` and ``vgr calibrate handeye|robot-world --images DIR
--poses FILE --board SPEC`` (or ``RUN.mcap --board SPEC``: a recording's images, camera model and robot
poses, :mod:`.recording`): the command-line glue of the board library.

:mod:`plugins.calibration.cli` owns the verb, the exit codes (0 usable, 1 unusable, 2 bad
input) and the ``--json`` / ``--report`` files; this module adds the options of the ``intrinsics``
kind and turns images into an ``Outcome``: detection (every rejected image listed with its reason),
:func:`calibrate_intrinsics`, the text report, and in the report folder ``coverage.png``,
``camera.json`` (the camera document alone, which ``--intrinsics FILE`` of later steps reads as
well as the ``--json`` result) and ``detections.json`` (every corner found, per view, and the
views left out or rejected with the reason: :mod:`.detections_file`).

Bad input (exit 2): a board spec that does not parse, no image given, or none of the images readable.
Images that are readable but show no board are not bad input: they are listed, and with fewer than
3 views left the result is ``failed`` (exit 1).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from plugins.calibration.boards.recording import DEFAULT_IMAGE_TOPICS

if TYPE_CHECKING:
    from plugins.calibration.boards.detect import Detection, Rejection
    from plugins.calibration.report import Outcome
    from plugins.camera.pinhole import CameraModel

BOARD_HELP = (
    "the board: chessboard:COLSxROWS:SQUARE (squares, e.g. chessboard:25x18:15mm), "
    "charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy], circles:COLSxROWS:SPACING[:asymmetric], or a board file"
)


def intrinsics_options(p: argparse.ArgumentParser) -> None:
    """The options of ``vgr calibrate intrinsics``."""
    p.add_argument("--board", required=True, metavar="SPEC", help=BOARD_HELP)
    p.add_argument(
        "--model",
        choices=["auto", "standard", "rational", "fisheye"],
        default="auto",
        help="lens distortion model; auto: standard (5 coefficients) or rational (8), chosen by BIC",
    )
    p.add_argument("--keep-outliers", action="store_true", help="keep views whose RMS is far above the others'")
    p.add_argument("--workers", type=int, default=None, help="detection threads (default: the CPU count)")


def run_intrinsics(args: argparse.Namespace) -> Outcome:
    """Detect, calibrate, and package the result for :func:`plugins.calibration.cli.run_kind`."""
    from plugins.calibration.boards.detect import detect_images, image_files
    from plugins.calibration.boards.detections_file import detections_document, write_detections
    from plugins.calibration.boards.intrinsics import calibrate_intrinsics, plot_coverage
    from plugins.calibration.inputs import CalibrationInputError
    from plugins.calibration.report import Outcome
    from plugins.camera.board_spec import parse_board

    board = parse_board(args.board)
    files = image_files(args.images)
    if not files:
        raise CalibrationInputError(f"no image files in {', '.join(map(str, args.images))}")
    if args.json is not None and any(Path(args.json).resolve() == f.resolve() for f in files):
        raise CalibrationInputError(f"--json {args.json} is one of the images: choose another output")
    detections = detect_images(files, board, workers=args.workers)
    if not detections.found and all(r.unreadable for r in detections.rejected):
        reasons = "; ".join(f"{Path(r.name).name}: {r.reason}" for r in detections.rejected[:5])
        raise CalibrationInputError(f"none of the {len(files)} image(s) could be read ({reasons})")
    cal = calibrate_intrinsics(detections, model=args.model, reject_outliers=not args.keep_outliers)
    notes = [f"board found in {len(detections.found)} of {len(files)} image(s): {board.describe()}"]

    def write_files(d: Path) -> None:
        if cal.views:
            plot_coverage(cal, detections, d / "coverage.png")
            cal.camera.save(d / "camera.json")
        left = {v.name: "its reprojection is far above the other views' (an outlier)" for v in cal.views if not v.used}
        write_detections(d / "detections.json", detections_document(board, detections.found, detections.rejected, left))

    text = cal.report_text()
    return Outcome(cal.to_result(), notes, text, {"Images": f"```\n{text}\n```"}, write_files)


def handeye_image_options(p: argparse.ArgumentParser) -> None:
    """The options of ``vgr calibrate handeye|robot-world --images DIR --poses FILE --board SPEC``."""
    g = p.add_argument_group("from images (instead of DATA)")
    g.add_argument(
        "--images", type=Path, metavar="DIR", help="folder of board images (png / jpg / bmp), sorted by name"
    )
    g.add_argument(
        "--poses",
        type=Path,
        metavar="FILE",
        help="robot flange poses, one per image in the same order: 4x4 rows (16 numbers, row-major, m), "
        "UR pose CSV (x y z rx ry rz) or vgr JSON",
    )
    g.add_argument("--board", metavar="SPEC", help=BOARD_HELP)
    g.add_argument("--intrinsics", type=Path, metavar="FILE", help="camera file (default: calibrated from the images)")
    g.add_argument("--refine-intrinsics", action="store_true", help="refine the intrinsics with the hand-eye")
    g.add_argument("--no-holdout", action="store_true", help="skip the leave-one-view-out reprojection figures")
    g.add_argument("--workers", type=int, default=None, help="detection threads (default: the CPU count)")
    r = p.add_argument_group("from a recording's images (DATA.mcap with --board SPEC)")
    r.add_argument("--image-topic", default=DEFAULT_IMAGE_TOPICS["image"], help="MCAP: RawImage of the board")
    r.add_argument(
        "--camera-info-topic",
        default=DEFAULT_IMAGE_TOPICS["camera_info"],
        help="MCAP: CameraInfo of those images (unless --intrinsics FILE)",
    )


def run_handeye_images(args: argparse.Namespace, kind: str) -> Outcome:
    """Images + robot poses (a folder and a pose file, or a recording) -> hand-eye (:mod:`.handeye_images`),
    packaged for the CLI."""
    from plugins.calibration.inputs import CalibrationInputError

    if args.images is None and args.data is None:
        raise CalibrationInputError("give DATA (a sample file or recording) or --images DIR --poses FILE --board SPEC")
    if args.data is not None and args.images is not None:
        raise CalibrationInputError("give DATA or --images, not both")
    if args.board is None:
        raise CalibrationInputError("--images needs --poses FILE and --board SPEC; a recording's images need --board")
    if args.data is not None:
        return _run_recording(args, kind)
    if args.poses is None:
        raise CalibrationInputError("--images needs --poses FILE and --board SPEC")
    return _run_folder(args, kind)


def _run_recording(args: argparse.Namespace, kind: str) -> Outcome:
    """DATA.mcap --board SPEC: the recording's images, camera model and robot poses (:mod:`.recording`)."""
    from plugins.calibration.boards.recording import recorded_views
    from plugins.calibration.inputs import CalibrationInputError
    from plugins.camera.board_spec import parse_board
    from plugins.camera.pinhole import CameraModel

    if args.data.suffix.lower() != ".mcap":
        raise CalibrationInputError(f"{args.data}: --board with DATA reads a recording's images: DATA must be .mcap")
    if args.poses is not None:
        raise CalibrationInputError("--poses goes with --images; a recording's robot poses come from --robot-topic")
    if args.mm:
        raise CalibrationInputError("--mm applies to plain files; recordings are in metres")
    board = parse_board(args.board)
    rv = recorded_views(
        args.data,
        board,
        image_topic=args.image_topic,
        camera_info_topic=None if args.intrinsics is not None else args.camera_info_topic,
        robot_topic=args.robot_topic,
        pairing={"mode": args.pair, "max_skew_s": args.max_skew_s, "drop_unmatched": args.drop_unmatched},
    )
    notes = [*rv.notes, f"board found in {len(rv.views)} of {len(rv.views) + len(rv.rejected)} image(s): "
             f"{board.describe()}"]  # fmt: skip
    notes += [f"{r.name}: {r.reason}; its robot pose is dropped" for r in rv.rejected]
    if args.intrinsics is not None:
        camera = CameraModel.load(args.intrinsics)
        notes.append(f"intrinsics from {args.intrinsics}")
    else:
        assert rv.camera is not None
        camera = rv.camera
        notes.append(f"intrinsics from {args.camera_info_topic} ({camera.ros_distortion_model})")
    return _outcome(args, kind, rv.views, rv.T_base_tcp, camera, rv.rejected, notes)


def _run_folder(args: argparse.Namespace, kind: str) -> Outcome:
    """--images DIR --poses FILE --board SPEC."""
    from plugins.calibration.boards.detect import detect_images, image_files
    from plugins.calibration.boards.handeye_images import pair_views
    from plugins.calibration.boards.intrinsics import calibrate_intrinsics
    from plugins.calibration.boards.robot_poses import load_robot_poses
    from plugins.calibration.inputs import CalibrationInputError
    from plugins.calibration.report import Outcome
    from plugins.camera.board_spec import parse_board
    from plugins.camera.pinhole import CameraModel

    board = parse_board(args.board)
    files = image_files([args.images])
    if not files:
        raise CalibrationInputError(f"no image files (png / jpg / bmp) in {args.images}")
    poses = load_robot_poses(args.poses, length_unit="mm" if args.mm else None)
    if len(poses) != len(files):
        raise CalibrationInputError(
            f"{len(files)} image(s) in {args.images} but {len(poses)} robot pose(s) in {args.poses}: images are "
            "paired with poses in sorted file order, one pose per image"
        )
    detections = detect_images(files, board, workers=args.workers)
    notes = [f"board found in {len(detections.found)} of {len(files)} image(s): {board.describe()}"]
    notes += [f"{Path(r.name).name}: {r.reason}; its robot pose is dropped" for r in detections.rejected]
    if args.intrinsics is not None:
        camera = CameraModel.load(args.intrinsics)
        notes.append(f"intrinsics from {args.intrinsics}")
    else:
        cal = calibrate_intrinsics(detections)
        if not cal.usable:
            return Outcome(cal.to_result(), notes, cal.report_text())
        camera = cal.camera
        notes.append(f"intrinsics calibrated from the same images: RMS {cal.rms_px:.3f} px ({cal.model_choice})")
    views, M, rejected = pair_views(files, detections, poses)
    return _outcome(args, kind, views, M, camera, rejected, notes)


def _outcome(
    args: argparse.Namespace,
    kind: str,
    views: list[Detection],
    M: np.ndarray,
    camera: CameraModel,
    rejected: list[Rejection],
    notes: list[str],
) -> Outcome:
    """The images pipeline on paired views, and its report."""
    from plugins.calibration.boards.detections_file import detections_document, write_detections
    from plugins.calibration.boards.handeye_images import calibrate_handeye_images
    from plugins.calibration.report import Outcome
    from plugins.camera.board_spec import parse_board

    out = calibrate_handeye_images(
        views,
        M,
        camera,
        kind="robot_world" if kind == "robot_world" else "hand_eye",
        setup=args.setup or "eye_in_hand",
        refine_intrinsics=args.refine_intrinsics,
        rejected=rejected,
        holdout=not args.no_holdout,
    )
    m = out.result.metrics
    text = ""
    if out.refinement is not None:
        text = (
            f"reprojection through the robot poses: {m['rms_px']:.3f} px RMS (fit), "
            f"{m['holdout_rms_px']:.3f} px (each view held out); board pose from PnP {m['board_pose_rms_px']:.3f} px\n"
            f"board's world pose over the views: spread {m['world_spread_trans_rms_m'] * 1e3:.3f} mm / "
            f"{np.degrees(m['world_spread_rot_rms_rad']):.4f} deg RMS"
        )

    def write_files(d: Path) -> None:
        if out.refinement is not None:
            out.refinement.camera.save(d / "camera.json")
        why = (
            "its corners do not fit through its robot pose like the other views' (the board moved, or a poor detection)"
        )
        left = dict.fromkeys(out.outlier_views, why)
        doc = detections_document(parse_board(args.board), views, rejected, left)
        write_detections(d / "detections.json", doc)

    return Outcome(out.result, notes, text, {"Images": f"```\n{text}\n```"} if text else {}, write_files)
