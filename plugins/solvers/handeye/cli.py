"""Command-line front end of the hand-eye library, ready to be wired as ``vgr calibrate handeye|robot-world``.

``python -m plugins.solvers.handeye.cli DATA [--setup eye_to_hand] [--kind robot_world] [--mm]
[--robot-noise DEG MM] [--camera-noise DEG MM] [--loss huber] [--json OUT]`` loads a JSON or CSV
sample file (see docs/handeye.md), calibrates, prints the mm/degree report and optionally writes the
CalibrationResult as JSON. Exit code 0 for a usable result, 1 for degenerate/failed, 2 for bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from plugins.solvers.handeye.io import load_pose_pairs
from plugins.solvers.handeye.noise import NoiseModel
from plugins.solvers.handeye.problem import check_setup
from plugins.solvers.handeye.report import format_report
from plugins.solvers.handeye.solver import calibrate_hand_eye, calibrate_robot_world

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="vgr calibrate handeye", description=__doc__.split("\n")[0])
    ap.add_argument("data", type=Path, help="sample file (.json or .csv)")
    ap.add_argument("--setup", choices=["eye_in_hand", "eye_to_hand"], default=None)
    ap.add_argument("--kind", choices=["hand_eye", "robot_world"], default="hand_eye")
    ap.add_argument("--mm", action="store_true", help="translations in the file are millimetres")
    ap.add_argument("--robot-noise", nargs=2, type=float, metavar=("DEG", "MM"), default=None)
    ap.add_argument("--camera-noise", nargs=2, type=float, metavar=("DEG", "MM"), default=None)
    ap.add_argument("--loss", choices=["huber", "cauchy", "linear"], default="huber")
    ap.add_argument("--json", type=Path, default=None, help="write the CalibrationResult here")
    args = ap.parse_args(argv)
    try:
        samples = load_pose_pairs(args.data, length_unit="mm" if args.mm else None)
        setup = check_setup(args.setup or samples.setup or "eye_in_hand")
        noise = None
        if args.robot_noise or args.camera_noise:
            if not args.camera_noise:
                ap.error("--camera-noise is needed when a noise model is declared")
            robot = args.robot_noise or (0.0, 0.0)
            noise = NoiseModel.isotropic(robot[0], robot[1], args.camera_noise[0], args.camera_noise[1])
        solve = calibrate_robot_world if args.kind == "robot_world" else calibrate_hand_eye
        result = solve(samples.T_base_tcp, samples.T_cam_target, setup=setup, noise=noise, loss=args.loss)
    except ValueError as exc:  # HandEyeInputError and unknown set-up names
        print(f"bad input: {exc}", file=sys.stderr)
        return 2
    print(format_report(result))
    if args.json:
        args.json.write_text(result.to_json(indent=1))
    return 0 if result.usable else 1


if __name__ == "__main__":
    raise SystemExit(main())
