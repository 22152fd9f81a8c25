"""``vgr gap``: the model-gap workflow from the command line (a verb module of :mod:`engine.cli.main`).

    vgr gap --model MODEL --data DATA [--report DIR] [--noise-mm SIGMA] [--calibrate frame,tool,joints]
    vgr gap check --model STORED --data NEW [--refit tool] [--report DIR] [--noise-mm SIGMA]
    vgr gap --camera IMAGES --board SPEC [--report DIR]    (the camera model: plugins/model_gap/camera)
    vgr gap --depth CAPTURES [--target known|fit] [--report DIR]    (a depth camera: plugins/model_gap/depth)

MODEL is a shipped robot (``ur5e``, ``abb_irb120``), a robot model file, or an augmented model a
previous run wrote; DATA a CSV (docs/model_gap.md) or a vgr recording (.mcap). Exit codes: 0 the
gap is explained or there is none, 1 a gap remains unexplained, 2 bad input, 3 explained up to a
tie (the augmented model predicts the data to the noise, but part of the gap is one of several
effects the data cannot tell apart: the report says what would separate them).

``check`` scores a model vgr wrote (augmented, calibrated) on new measurements, refitting nothing
(or the tool point, ``--refit tool``): mean / RMS / max error against the noise floor. Exit codes:
0 the model predicts the data, 1 it leaves a systematic gap, 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from rich.console import Console

from engine import run_folder
from engine.exit_codes import ExitCode
from plugins.model_gap.camera.cli import add_camera_arguments, cmd_camera_gap
from plugins.model_gap.depth.cli import add_depth_arguments, cmd_depth_gap, refuse_depth_options
from plugins.model_gap.selection_options import check_alpha_arg, check_selection_args
from plugins.model_gap.verdicts import VERDICT_EXIT_CODES
from plugins.model_gap.workflow_options import check_end_args

#: the exit code of each workflow verdict (plugins/model_gap/verdicts.py: the table every workflow uses)
EXIT_CODES = VERDICT_EXIT_CODES


def add_verbs(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "gap",
        help="compare a robot model with measurements, name the missing effect, add it (model-gap workflow)",
        description="Compare a robot model with measurements, name the missing physical effect, add it and "
        "show the gap shrink (docs/model_gap.md). 'vgr gap check' scores a stored model on new measurements.",
        epilog="exit codes: 0 the gap is explained or there is none, 1 a gap remains unexplained, 2 bad "
        "input, 3 explained up to a tie (part of the gap is one of several effects the data cannot tell apart). "
        "vgr gap check: 0 the stored model predicts the new data, 1 a systematic gap is left, 2 bad input",
    )
    p.add_argument(
        "action",
        nargs="?",
        choices=["check"],
        metavar="check",
        help="check: score a stored model (augmented_model.yaml, a vgr calibrate kinematics result) on new data, "
        "refitting nothing (exit 0 it predicts them, 1 a systematic gap is left, 2 bad input)",
    )
    p.add_argument("--model", help="shipped robot name, robot model file or augmented model file (required)")
    p.add_argument("--data", help="CSV (q1_deg.., x_mm, y_mm, z_mm, ...) or a .mcap recording (required)")
    p.add_argument("--report", metavar="DIR", help="write gap_report.json, figures and model files to DIR")
    p.add_argument(
        "--noise-mm",
        type=float,
        help="measurement noise, 1 sigma per axis in mm (default: the CSV's sigma_mm column, else estimated); "
        "--depth: the stated range noise's constant term, mm",
    )
    p.add_argument(
        "--calibrate",
        default=None,
        help="baseline calibration before any effect (default: the measurement frame, the tool and the joint "
        "geometry, as far as the data identify them); or a subset: frame, tool, joints joined by commas, or none",
    )
    p.add_argument("--max-effects", type=int, default=4, help="at most this many effects are added (default 4)")
    p.add_argument("--alpha", type=float, default=1e-3, help="family-wise false-positive rate per round (1e-3)")
    p.add_argument("--folds", type=int, default=5, help="cross-validation folds (5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the cross-validation folds")
    p.add_argument(
        "--outlier-alpha",
        type=float,
        default=0.01,
        help="gross-error screen: probability that a campaign of Gaussian noise loses any good sample (0.01); "
        "0 keeps every sample",
    )
    p.add_argument(
        "--min-share",
        type=float,
        default=0.3,
        help="when structure is left, a catalog effect stays only if it explains this share of what the model "
        "without it leaves (0.3)",
    )
    p.add_argument(
        "--noise-trust",
        type=float,
        default=2.0,
        help="a stated noise is believed to this factor: residuals beyond it are a gap (2)",
    )
    p.add_argument("--joint-topic", help="recordings: the JointState topic (default: the only one)")
    p.add_argument("--measurement-topic", help="recordings: the TrackerPose/PoseStamped topic of the measurements")
    p.add_argument(
        "--payload-kg",
        type=float,
        help="mass at the TCP for every sample, kg (default: the CSV's payload_kg column, or the robot "
        "stage's payload_kg in a recording's recipe)",
    )
    p.add_argument("--sensor", default="sensor", help="CSV: the name of the measuring sensor (where latency acts)")
    p.add_argument("--json", action="store_true", help="print gap_report.json to stdout instead of tables")
    p.add_argument(
        "--plugin",
        action="append",
        metavar="PLUGIN",
        help="also load effects from this plugin: an installed one's name, or a plugin file (as a recipe's plugins:)",
    )
    p.add_argument(
        "--refit",
        default=None,
        help="check: what to refit on the new data: tool (the measured point on the flange, for a new tool); "
        "default nothing",
    )
    add_camera_arguments(p)  # vgr gap --camera IMAGES --board SPEC: the camera model (plugins/model_gap/camera)
    add_depth_arguments(p)  # vgr gap --depth CAPTURES: a depth camera's range errors (plugins/model_gap/depth)
    p.set_defaults(func=cmd_gap)


def _levels(text: str | None) -> tuple[str, ...] | None:
    """The ``--calibrate`` levels; None (the default) is the full calibration the data identify."""
    if text is None:
        return None
    parts = tuple(x.strip() for x in text.split(",") if x.strip())
    return () if parts in ((), ("none",)) else parts


def cmd_gap(args: argparse.Namespace) -> int:
    from plugins.model_gap.analyse import analyse_gap
    from plugins.model_gap.core import GapConfig, SelectionConfig
    from plugins.model_gap.core.report import report_dict

    if args.depth is not None:
        return cmd_depth_gap(args)
    refuse_depth_options(args)
    if args.camera is not None:
        return cmd_camera_gap(args)
    if args.model is None or args.data is None:
        raise ValueError(
            "vgr gap needs --model and --data (or --camera IMAGES --board SPEC for the camera model, "
            "--depth CAPTURES for a depth camera)"
        )
    if args.action == "check":
        return cmd_check(args)
    if args.refit is not None:
        raise ValueError("--refit is an option of vgr gap check (the workflow refits everything)")
    check_selection_args(args)
    check_end_args(args)
    cfg = GapConfig(
        SelectionConfig(alpha=args.alpha, cv_folds=args.folds, seed=args.seed),
        max_effects=args.max_effects,
        noise_trust=args.noise_trust,
        min_share=args.min_share,
        outlier_alpha=args.outlier_alpha,
    )
    result = analyse_gap(args.model, args.data, calibrate=_levels(args.calibrate), config=cfg, **_common(args))
    if args.json:
        _print_json(report_dict(result))
    return EXIT_CODES[result.verdict]


def _common(args: argparse.Namespace) -> dict[str, Any]:
    """The arguments ``vgr gap`` and ``vgr gap check`` give their library function alike: the noise,
    the report folder, the console (none with --json), the effect families (with --plugin's) and the
    options that say how to read the data file (those given)."""
    from plugins.model_gap.families import families_from_registry

    data_options = {k: getattr(args, k) for k in ("joint_topic", "measurement_topic", "sensor", "payload_kg")}
    return {
        "noise_mm": args.noise_mm,
        "report_dir": None if args.report is None else run_folder.new_folder(args.report, "--report"),
        "console": None if args.json else Console(width=None if sys.stdout.isatty() else 160),
        "families": families_from_registry(tuple(args.plugin or ())),
        "data_options": {k: v for k, v in data_options.items() if v is not None},
    }


def _print_json(report: dict[str, Any]) -> None:
    from engine.plain_data import plain

    print(json.dumps(plain(report, nan_as_none=True), indent=2))


CHECK_EXIT_CODES = {"ok": ExitCode.OK, "gap": ExitCode.NOT_OK}


def cmd_check(args: argparse.Namespace) -> int:
    """``vgr gap check``: score a stored model on new data (:func:`.check.check_model`)."""
    from plugins.model_gap.check import check_model
    from plugins.model_gap.core.check import check_report_dict

    if args.calibrate is not None:
        raise ValueError("--calibrate does not apply to vgr gap check: it refits nothing (or --refit tool)")
    check_alpha_arg(args.alpha)
    result = check_model(args.model, args.data, refit=_levels(args.refit) or (), alpha=args.alpha, **_common(args))
    if args.json:
        _print_json(check_report_dict(result))
    return CHECK_EXIT_CODES[result.verdict]
