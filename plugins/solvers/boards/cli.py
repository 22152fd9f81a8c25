"""``vgr calibrate intrinsics IMAGES... --board SPEC``: the command-line glue of the board library.

:mod:`plugins.solvers.calibrate_cli` owns the verb, the exit codes (0 usable, 1 unusable, 2 bad
input) and the ``--json`` / ``--report`` files; this module adds the options of the ``intrinsics``
kind and turns images into an ``Outcome``: detection (every rejected image listed with its reason),
:func:`calibrate_intrinsics`, the text report, and in the report folder ``coverage.png`` and
``camera.json`` (the camera document alone, which ``--intrinsics FILE`` of later steps reads as
well as the ``--json`` result).

Bad input (exit 2): a board spec that does not parse, no image given, or none of the images readable.
Images that are readable but show no board are not bad input: they are listed, and with fewer than
3 views left the result is ``failed`` (exit 1).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from plugins.solvers.calibrate_cli import Outcome

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
    """Detect, calibrate, and package the result for :func:`plugins.solvers.calibrate_cli.run_kind`."""
    from plugins.solvers.boards.detect import detect_images, image_files
    from plugins.solvers.boards.intrinsics import calibrate_intrinsics, plot_coverage
    from plugins.solvers.boards.spec import parse_board
    from plugins.solvers.calibrate_cli import Outcome
    from plugins.solvers.calibration_inputs import CalibrationInputError

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

    text = cal.report_text()
    return Outcome(cal.to_result(), notes, text, {"Images": f"```\n{text}\n```"}, write_files)
