"""``vgr gap --camera IMAGES --board SPEC``: the camera model-gap workflow from the command line.

    vgr gap --camera IMAGES... --board SPEC [--report DIR] [--json] [--alpha A] [--folds K] [--seed S]
            [--max-effects N]

IMAGES are image files, folders of images or one ``detections.json`` (:mod:`.inputs`). The verb is the
robot ``vgr gap``'s (plugins/model_gap/cli.py adds these options and hands over here when
``--camera`` is given); the exit codes are the same: 0 explained or no gap, 1 a gap left unexplained,
2 bad input (``vgr.invalid/1`` with ``--json``), 3 explained up to a tie. ``--json`` prints the
``vgr.camera_gap_report/1`` document (:mod:`.report`); ``--report DIR`` writes it as
``camera_gap_report.json`` with the detections (``detections.json``) the workflow used.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from plugins.model_gap.gap_report_parts import show_report, write_report_file
from plugins.model_gap.selection_options import check_selection_args
from plugins.model_gap.workflow_options import refuse_options

__all__ = ["ROBOT_ONLY_OPTIONS", "add_camera_arguments", "cmd_camera_gap"]

#: ``vgr gap`` options of the robot workflow that mean nothing for the camera
ROBOT_ONLY_OPTIONS = (
    "model", "data", "noise_mm", "calibrate", "joint_topic", "measurement_topic", "payload_kg", "plugin", "refit",
)  # fmt: skip


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """The camera options of ``vgr gap`` (the others it shares: --report, --json, --alpha, --folds,
    --seed, --max-effects)."""
    p.add_argument(
        "--camera",
        nargs="+",
        metavar="IMAGES",
        help="camera model gap: board images, folders of images or a detections.json (with --board; "
        "docs/camera_gap.md)",
    )
    p.add_argument("--board", help="camera model gap: the board spec (chessboard:25x18:15mm) or a board file")


def _check_options(args: argparse.Namespace) -> None:
    refuse_options(args, ROBOT_ONLY_OPTIONS, "options of the robot workflow; the camera gap takes --camera and --board")
    if not args.board:
        raise ValueError("--camera needs --board SPEC (e.g. chessboard:25x18:15mm) or a board file")
    check_selection_args(args)


def cmd_camera_gap(args: argparse.Namespace) -> int:
    """Run the camera workflow for ``vgr gap --camera``; returns the exit code of the verdict."""
    from engine import run_folder
    from plugins.calibration.boards.detections_file import detections_document, write_detections
    from plugins.model_gap.camera.inputs import load_views
    from plugins.model_gap.camera.report import VERDICT_EXIT_CODES, print_report, report_dict
    from plugins.model_gap.camera.workflow import CameraGapConfig, run_camera_gap

    _check_options(args)
    folder = None if args.report is None else run_folder.new_folder(args.report, "--report")
    dets = load_views(args.camera, args.board)
    cfg = CameraGapConfig(alpha=args.alpha, folds=args.folds, seed=args.seed, max_effects=args.max_effects)
    size = dets.image_size
    assert size is not None  # load_views refuses a set without a detection
    result = run_camera_gap(dets.found, size, cfg)
    rejected = [{"name": Path(r.name).name, "reason": r.reason} for r in dets.rejected]
    doc = report_dict(result, rejected, dets.board.spec)
    if folder is not None:
        doc["files"] = {"report": str(folder / "camera_gap_report.json"), "detections": str(folder / "detections.json")}
        write_detections(folder / "detections.json", detections_document(dets.board, dets.found, dets.rejected))
        write_report_file(folder / "camera_gap_report.json", doc)
    show_report(doc, args.json, print_report)
    return int(VERDICT_EXIT_CODES[result.verdict])
