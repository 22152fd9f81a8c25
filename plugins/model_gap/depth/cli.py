"""``vgr gap --depth CAPTURES``: the depth camera's model-gap workflow from the command line.

    vgr gap --depth CAPTURES... [--target auto|known|fit] [--report DIR] [--json] [--alpha A] [--folds K]
            [--seed S] [--max-effects N] [--noise-mm A] [--noise-mm-per-m2 B] [--outlier-alpha P]
            [--min-share S] [--noise-trust F] [--topic T] [--target-frame F]

CAPTURES are ``vgr.depth_captures/1`` files (.npz), folders of them, or a vgr recording (.mcap) with
``--topic`` (its depth images, default the only ``.../depth``) and ``--target-frame`` (the target's
frame in the recording's ``truth/part_poses``: a simulated cell) (:mod:`.inputs`). ``--noise-mm`` and
``--noise-mm-per-m2`` state the sensor's noise law ``sigma(z) = A + B z^2`` (mm, z in m); without them
it is estimated from the residuals. The verb is the robot ``vgr gap``'s (plugins/model_gap/cli.py adds
these options and hands over here when ``--depth`` is given); the exit codes are the same: 0 explained
or no gap, 1 a gap left unexplained, 2 bad input (``vgr.invalid/1`` with ``--json``), 3 explained up to
a tie. ``--json`` prints the ``vgr.depth_gap_report/1`` document (:mod:`.report`); ``--report DIR``
writes it as ``depth_gap_report.json`` with the captures the workflow read (``captures.npz``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING

from plugins.model_gap.gap_report_parts import show_report, write_report_file
from plugins.model_gap.selection_options import check_selection_args
from plugins.model_gap.workflow_options import check_end_args, refuse_options

if TYPE_CHECKING:
    from plugins.model_gap.depth.data import SigmaLaw

__all__ = ["DEPTH_ONLY_OPTIONS", "add_depth_arguments", "cmd_depth_gap", "refuse_depth_options"]

#: ``vgr gap`` options of the robot and camera workflows that mean nothing for the depth camera
OTHER_OPTIONS = (
    "model", "data", "calibrate", "joint_topic", "measurement_topic", "payload_kg", "plugin", "refit", "camera",
    "board",
)  # fmt: skip
#: the options only ``--depth`` reads (refused by the other workflows: they would be ignored)
DEPTH_ONLY_OPTIONS = ("target", "topic", "target_frame", "noise_mm_per_m2")


def add_depth_arguments(p: argparse.ArgumentParser) -> None:
    """The depth options of ``vgr gap`` (the others it shares: --report, --json, --alpha, --folds, --seed,
    --max-effects, --noise-mm, --outlier-alpha, --min-share, --noise-trust)."""
    p.add_argument(
        "--depth",
        nargs="+",
        metavar="CAPTURES",
        help="depth camera model gap: depth captures of a flat target (.npz files, folders of them or a "
        ".mcap recording; docs/depth_gap.md)",
    )
    p.add_argument(
        "--target",
        choices=("auto", "known", "fit"),
        help="depth: the target's pose is known per capture, or its plane is fitted per capture "
        "(default auto: known when every capture has one)",
    )
    p.add_argument(
        "--noise-mm-per-m2",
        type=float,
        help="depth: the stated noise law's z^2 term, sigma(z) = NOISE_MM + this * z^2 (mm, z in m)",
    )
    p.add_argument("--topic", help="depth, recordings: the depth Image topic (default: the only .../depth)")
    p.add_argument(
        "--target-frame",
        help="depth, recordings: the target's frame in truth/part_poses (default: none, the plane is fitted)",
    )


def refuse_depth_options(args: argparse.Namespace) -> None:
    """ValueError when a depth-only option is given to another workflow (it would be ignored)."""
    given = [f"--{n.replace('_', '-')}" for n in DEPTH_ONLY_OPTIONS if getattr(args, n, None) is not None]
    if given:
        raise ValueError(f"{', '.join(given)}: options of the depth gap (vgr gap --depth CAPTURES)")


def _check_options(args: argparse.Namespace) -> None:
    refuse_options(args, OTHER_OPTIONS, "options of the robot or camera workflow; the depth gap takes --depth CAPTURES")
    check_selection_args(args)
    check_end_args(args)
    for name in ("noise_mm", "noise_mm_per_m2"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ValueError(f"--{name.replace('_', '-')} must be a finite sigma >= 0, got {value}")
    if args.target_frame is not None and args.target == "fit":
        raise ValueError("--target-frame gives the target's pose: it contradicts --target fit")


def _stated_noise(args: argparse.Namespace) -> SigmaLaw | None:
    """The ``--noise-mm`` / ``--noise-mm-per-m2`` law (m), or None (then a file's, else estimated)."""
    from plugins.model_gap.depth.data import SigmaLaw

    if args.noise_mm is None and args.noise_mm_per_m2 is None:
        return None
    return SigmaLaw((args.noise_mm or 0.0) / 1e3, (args.noise_mm_per_m2 or 0.0) / 1e3)


def cmd_depth_gap(args: argparse.Namespace) -> int:
    """Run the depth workflow for ``vgr gap --depth``; returns the exit code of the verdict."""
    from engine import run_folder
    from plugins.model_gap.depth.inputs import load_captures, write_captures
    from plugins.model_gap.depth.report import VERDICT_EXIT_CODES, print_report, report_dict
    from plugins.model_gap.depth.workflow import DepthGapConfig, run_depth_gap

    _check_options(args)
    captures = load_captures(args.depth, target_frame=args.target_frame, topic=args.topic, sigma=_stated_noise(args))
    cfg = DepthGapConfig(
        alpha=args.alpha, folds=args.folds, seed=args.seed, max_effects=args.max_effects, target=args.target or "auto",
        outlier_alpha=args.outlier_alpha, noise_trust=args.noise_trust, min_share=args.min_share,
    )  # fmt: skip
    folder = None if args.report is None else run_folder.new_folder(args.report, "--report")
    result = run_depth_gap(captures, cfg)
    rejected = [{"name": name, "reason": why} for name, why in captures.rejected]
    doc = report_dict(result, rejected, ", ".join(str(Path(p)) for p in args.depth))
    if folder is not None:
        doc["files"] = {"report": str(folder / "depth_gap_report.json"), "captures": str(folder / "captures.npz")}
        write_captures(folder / "captures.npz", captures)
        write_report_file(folder / "depth_gap_report.json", doc)
    show_report(doc, args.json, print_report)
    return int(VERDICT_EXIT_CODES[result.verdict])
