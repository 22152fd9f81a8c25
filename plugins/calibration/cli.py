"""``vgr calibrate KIND DATA``: every calibration of vgr from a plain file or a vgr recording.

Kinds: ``handeye`` and ``robot-world`` (AX=XB / AX=ZB, docs/handeye.md), ``vive-desk`` and ``tcp``
(docs/vive_and_tcp.md), ``kinematics`` (docs/kinematic_calibration.md), ``intrinsics`` (camera
intrinsics from images of a calibration board: ``IMAGES... --board SPEC`` instead of DATA,
docs/calibration_boards.md, glue in :mod:`plugins.calibration.boards.cli`). DATA is one of the plain
formats those pages document (``.json`` / ``.csv``) or an MCAP recording made by ``vgr run``
(``.mcap``): then the samples are read from two topics (options ``--*-topic``, defaults matching the
``recipes/calibrate_*_sim.yaml`` recipes) and paired by stamp (``--pair stamp``, nearest within
``--max-skew-s``) or by order (``--pair order``); a count or stamp mismatch is an error unless
``--drop-unmatched``.

Output: the report in mm / degrees (estimate with 1-sigma, residuals, verdict, reasons, advice) on
stdout; ``--json OUT`` writes the CalibrationResult (never over the data file; an existing OUT, which
a ``calibration_file`` stage may be loading, is not replaced by an unusable result: that one goes to
OUT's name + ``.unusable``), ``--report DIR`` writes result.json, report.txt, summary.md (and for
kinematics convergence.png and before_after.txt); files are replaced atomically. Exit code (engine.exit_codes)
0: usable result (verdict ok); 3: usable, verdict warning (read the reasons); 1: degenerate or failed
(do not use it); 2: bad input (missing or malformed file, NaN, mixed units, too few samples, unpaired
samples).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from engine import run_folder
from engine.cli.arguments import ArgumentParser
from engine.exit_codes import ExitCode
from engine.files import replace_text
from engine.messages import JointState, PoseStamped, TrackerPose
from engine.recording.reader import Recording, RecordingError
from plugins.calibration.inputs import (
    CalibrationInputError,
    PairingOptions,
    hand_eye_samples,
    kinematic_samples,
    min_kinematic_samples,
    read_topic,
    tcp_camera_data,
    vive_desk_data,
)
from plugins.calibration.report import Outcome, format_result, kinematic_table, write_kinematic_files, write_report_dir

FILE_SUFFIXES = (".json", ".csv", ".mcap")

#: default topics: the stage and port names of recipes/calibrate_*_sim.yaml
DEFAULT_TOPICS = {
    "robot": "/poses/tcp_pose",
    "target": "/target/pose",
    "contact": "/poses/target",
    "tracker": "/poses/tracker_pose",
    "point": "/poses/point",
    "joints": "/poses/joint_state",
}


def _suffix(path: Path, extra: tuple[str, ...] = ()) -> str:
    s = path.suffix.lower()
    if not path.is_file():
        raise CalibrationInputError(f"{path}: no such file")
    if s not in FILE_SUFFIXES + extra:
        raise CalibrationInputError(f"{path}: unsupported file type {s!r} (use {', '.join(FILE_SUFFIXES + extra)})")
    return s


def _recording(path: Path) -> Recording:
    from engine.recording.reader import load

    return load(path)


def _pairing(args: argparse.Namespace) -> PairingOptions:
    return {"mode": args.pair, "max_skew_s": args.max_skew_s, "drop_unmatched": args.drop_unmatched}


# --------------------------------------------------------------------------- hand-eye / robot-world


def _hand_eye_options(p: argparse.ArgumentParser) -> None:
    from plugins.calibration.handeye import AccuracyTargets

    lim = AccuracyTargets()
    p.add_argument(
        "--setup",
        choices=["eye_in_hand", "eye_to_hand"],
        default=None,
        help="default: the file's, else found from the data (both fitted, the likelier taken; none when they tie)",
    )
    p.add_argument("--mm", action="store_true", help="translations in the file are millimetres")
    p.add_argument("--robot-noise", nargs=2, type=float, metavar=("DEG", "MM"), help="declared robot pose noise")
    p.add_argument("--camera-noise", nargs=2, type=float, metavar=("DEG", "MM"), help="declared camera pose noise")
    p.add_argument(
        "--camera-noise-xyz",
        nargs=6,
        type=float,
        metavar=("RX_DEG", "RY_DEG", "RZ_DEG", "TX_MM", "TY_MM", "TZ_MM"),
        help="declared camera pose noise per axis of the camera frame (z: the optical axis, where a "
        "depth camera's or PnP's error is largest); without a declared noise each axis is estimated",
    )
    p.add_argument(
        "--scale",
        choices=["fixed", "free"],
        default="fixed",
        help="free: the camera's translations are in an unknown unit (monocular, visual odometry); "
        "the scale is solved with its 1-sigma and reported",
    )
    for who, rot, trans in (
        ("camera", lim.max_camera_noise_rot_rad, lim.max_camera_noise_trans_m),
        ("robot", lim.max_robot_noise_rot_rad, lim.max_robot_noise_trans_m),
    ):
        p.add_argument(
            f"--max-{who}-noise",
            nargs=2,
            type=float,
            metavar=("DEG", "MM"),
            help=f"largest plausible {who} pose noise per axis (default {np.degrees(rot):g} {trans * 1e3:g}): "
            "an estimated noise above it fails the calibration",
        )
    p.add_argument("--loss", choices=["huber", "cauchy", "linear"], default="huber")
    p.add_argument("--robot-topic", default=DEFAULT_TOPICS["robot"], help="MCAP: PoseStamped T_base_tcp")
    p.add_argument("--target-topic", default=DEFAULT_TOPICS["target"], help="MCAP: PoseStamped T_cam_target")
    from plugins.calibration.boards.cli import handeye_image_options

    handeye_image_options(p)


def _hand_eye(kind: str) -> Callable[[argparse.Namespace], Outcome]:
    def run(args: argparse.Namespace) -> Outcome:
        from plugins.calibration.handeye import (
            AccuracyTargets,
            calibrate_hand_eye,
            calibrate_robot_world,
        )
        from plugins.calibration.handeye.io import YAML_SUFFIXES
        from plugins.calibration.handeye.problem import check_setup
        from plugins.calibration.handeye.stream_file import load_samples

        if args.images is not None or args.data is None or args.board is not None:
            from plugins.calibration.boards.cli import run_handeye_images

            if args.scale == "free" or args.camera_noise_xyz:
                raise CalibrationInputError(
                    "--scale free and --camera-noise-xyz apply to pose files: a board's size fixes the "
                    "scale, and its views' noise is measured from the corners"
                )

            return run_handeye_images(args, kind)
        notes: list[str] = []
        if _suffix(args.data, YAML_SUFFIXES) == ".mcap":
            if args.mm:
                raise CalibrationInputError("--mm applies to plain files; recordings are in metres")
            rec = _recording(args.data)
            robot = read_topic(rec, args.robot_topic, PoseStamped)
            target = read_topic(rec, args.target_topic, PoseStamped)
            samples, notes = hand_eye_samples(robot, target, **_pairing(args))
        else:
            samples = load_samples(args.data, length_unit="mm" if args.mm else None)
            notes += samples.notes
            if samples.dropped:
                notes.append(
                    f"dropped {len(samples.dropped)} sample(s) with a pose missing: {', '.join(samples.dropped)}"
                )
        n = len(samples.T_base_tcp)
        if n < 3:
            raise CalibrationInputError(
                f"{n} pose pair(s): hand-eye calibration needs at least 3 (better 10-15, rotated about different axes)"
            )
        setup = check_setup(args.setup or samples.setup) if args.setup or samples.setup else "auto"
        noise = _declared_noise(args)
        cov = samples.camera_covariances  # (each sample's own camera noise, from the file or the messages)
        if cov is not None and noise is not None:
            notes.append("the per-sample camera covariances of the data are not used: the camera noise is declared")
            cov = None
        accuracy = AccuracyTargets(**_noise_limits(args))
        solve = calibrate_robot_world if kind == "robot_world" else calibrate_hand_eye
        result = solve(
            samples.T_base_tcp, samples.T_cam_target, setup=setup, noise=noise, loss=args.loss,
            accuracy=accuracy, sample_ids=samples.ids or None, scale=args.scale,
            camera_covariances=cov,
        )  # fmt: skip
        result.metrics.update(samples.metrics)  # (a stream file's clock offset and its 1-sigma)
        return Outcome(result, notes)

    return run


def _declared_noise(args: argparse.Namespace) -> Any:
    """The NoiseModel of ``--robot-noise`` and ``--camera-noise`` / ``--camera-noise-xyz``, or None."""
    from plugins.calibration.handeye import NoiseModel
    from plugins.calibration.handeye.noise import PoseNoise

    if not (args.robot_noise or args.camera_noise or args.camera_noise_xyz):
        return None
    if args.camera_noise and args.camera_noise_xyz:
        raise CalibrationInputError("give --camera-noise or --camera-noise-xyz, not both")
    if not (args.camera_noise or args.camera_noise_xyz):
        raise CalibrationInputError("--camera-noise (or --camera-noise-xyz) is needed when a noise model is declared")
    robot = PoseNoise.from_deg_mm(*(args.robot_noise or (0.0, 0.0)))
    if args.camera_noise_xyz:
        values = np.asarray(args.camera_noise_xyz, dtype=float)
        if not (np.all(np.isfinite(values)) and np.all(values > 0)):
            raise CalibrationInputError(f"--camera-noise-xyz takes six positive numbers, got {args.camera_noise_xyz}")
        return NoiseModel(robot, PoseNoise.from_deg_mm(values[:3], values[3:]))
    return NoiseModel(robot, PoseNoise.from_deg_mm(*args.camera_noise))


def _noise_limits(args: argparse.Namespace) -> dict[str, float]:
    """``AccuracyTargets`` fields set by ``--max-camera-noise`` / ``--max-robot-noise`` (deg, mm)."""
    over: dict[str, float] = {}
    for who in ("camera", "robot"):
        value = getattr(args, f"max_{who}_noise")
        if value is None:
            continue
        deg, mm = value
        if not (deg > 0 and mm > 0 and np.isfinite(deg) and np.isfinite(mm)):
            raise CalibrationInputError(f"--max-{who}-noise takes two positive numbers (deg, mm), got {deg:g} {mm:g}")
        over[f"max_{who}_noise_rot_rad"] = float(np.radians(deg))
        over[f"max_{who}_noise_trans_m"] = mm * 1e-3
    return over


# --------------------------------------------------------------------------- Vive desk


def _vive_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tracker-sigma-mm", type=float, help="tracker position noise per axis (overrides the file)")
    p.add_argument("--tracker-sigma-deg", type=float, help="tracker rotation noise (overrides the file)")
    p.add_argument("--fixture-sigma-deg", type=float, help="fixture orientation scatter (overrides the file)")
    p.add_argument(
        "--tcp-prior-mm",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="TCP position in the tracker frame from CAD / caliper: a prior that makes one fixture orientation usable",
    )
    p.add_argument("--tcp-prior-sigma-mm", type=float, default=1.0, help="uncertainty of --tcp-prior-mm per axis")
    p.add_argument("--contact-topic", default=DEFAULT_TOPICS["contact"], help="MCAP: PoseStamped T_desktop_tcp")
    p.add_argument("--tracker-topic", default=DEFAULT_TOPICS["tracker"], help="MCAP: TrackerPose T_base_tracker")


def _vive(args: argparse.Namespace) -> Outcome:
    from engine.transforms import T_from_Rt
    from plugins.calibration.vive_desk import TrackerTcpPrior, calibrate_vive_desk, load_vive_csv, load_vive_json

    notes: list[str] = []
    suffix = _suffix(args.data)
    if suffix == ".mcap":
        rec = _recording(args.data)
        contacts = read_topic(rec, args.contact_topic, PoseStamped)
        trackers = read_topic(rec, args.tracker_topic, TrackerPose)
        data, notes = vive_desk_data(contacts, trackers, **_pairing(args))
    else:
        data = load_vive_json(args.data) if suffix == ".json" else load_vive_csv(args.data)
    nz = data.noise
    over = {
        "tracker_position_sigma_m": None if args.tracker_sigma_mm is None else args.tracker_sigma_mm * 1e-3,
        "tracker_rotation_sigma_rad": None if args.tracker_sigma_deg is None else np.radians(args.tracker_sigma_deg),
        "fixture_rotation_sigma_rad": None if args.fixture_sigma_deg is None else np.radians(args.fixture_sigma_deg),
    }
    if any(v is not None for v in over.values()):
        data = replace(data, noise=replace(nz, **{k: float(v) for k, v in over.items() if v is not None}))
    prior = None
    if args.tcp_prior_mm is not None:
        if not args.tcp_prior_sigma_mm > 0:
            raise CalibrationInputError("--tcp-prior-sigma-mm must be > 0")
        # position only: the rotation of T_tracker_tcp comes from the contacts' fixture orientations
        t = np.asarray(args.tcp_prior_mm, dtype=float) * 1e-3
        prior = TrackerTcpPrior(T_from_Rt(np.eye(3), t), args.tcp_prior_sigma_mm * 1e-3)
        notes.append(
            f"lever-arm prior: TCP at ({', '.join(f'{v:.1f}' for v in args.tcp_prior_mm)}) mm in the tracker "
            f"frame, {args.tcp_prior_sigma_mm:g} mm per axis"
        )
    return Outcome(calibrate_vive_desk(data, prior=prior), notes)


# --------------------------------------------------------------------------- TCP by camera


def _tcp_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera-sigma-mm", type=float, nargs="+", metavar="MM", help="1 or 3 (per camera axis) values")
    p.add_argument("--loss", choices=["linear", "soft_l1", "huber", "cauchy"], default="linear")
    p.add_argument("--robot-topic", default=DEFAULT_TOPICS["robot"], help="MCAP: PoseStamped T_base_flange")
    p.add_argument("--point-topic", default=DEFAULT_TOPICS["point"], help="MCAP: PoseStamped, TCP point in the camera")


def _tcp(args: argparse.Namespace) -> Outcome:
    from plugins.calibration.tcp_camera import TcpNoiseModel, calibrate_tcp_camera, load_tcp_csv, load_tcp_json

    notes: list[str] = []
    suffix = _suffix(args.data)
    sigma = None
    if args.camera_sigma_mm:
        if len(args.camera_sigma_mm) not in (1, 3):
            raise CalibrationInputError("--camera-sigma-mm takes 1 or 3 values")
        sigma = tuple(np.broadcast_to(np.asarray(args.camera_sigma_mm, float) * 1e-3, (3,)).tolist())
    if suffix == ".mcap":
        rec = _recording(args.data)
        robot = read_topic(rec, args.robot_topic, PoseStamped)
        points = read_topic(rec, args.point_topic, PoseStamped)
        noise = TcpNoiseModel(camera_sigma_m=sigma) if sigma else None
        data, notes = tcp_camera_data(robot, points, noise=noise, **_pairing(args))
    else:
        data = load_tcp_json(args.data) if suffix == ".json" else load_tcp_csv(args.data)
        if sigma:
            data = replace(data, noise=replace(data.noise, camera_sigma_m=sigma))
    return Outcome(calibrate_tcp_camera(data, loss=args.loss), notes)


# --------------------------------------------------------------------------- kinematics


def _kinematics_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default="ur5e", help="nominal robot model: a shipped name or a model file")
    p.add_argument("--tool-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="nominal tool point on the flange")
    p.add_argument("--parameterisation", choices=["dh", "mdh", "poe"], default=None, help="default: the model's")
    p.add_argument("--noise-mm", type=float, default=0.05, help="measurement noise per axis (default 0.05)")
    p.add_argument("--noise-deg", type=float, default=float(np.degrees(1e-4)), help="orientation noise (full pose)")
    p.add_argument("--trust-noise", action="store_true", help="covariance from the stated noise, not the residuals")
    p.add_argument("--holdout", type=Path, help="held-out samples (.csv / .json) for the before/after table")
    p.add_argument("--holdout-fraction", type=float, default=0.25, help="else this share of DATA is held out")
    p.add_argument("--full-pose", action="store_true", help="MCAP: the measurements carry the tool orientation")
    p.add_argument("--joints-topic", default=DEFAULT_TOPICS["joints"], help="MCAP: JointState")
    p.add_argument("--point-topic", default=DEFAULT_TOPICS["point"], help="MCAP: PoseStamped, measured tool point")


def _kinematics(args: argparse.Namespace) -> Outcome:
    from engine.transforms import T_from_Rt
    from plugins.calibration.kinematics import KinematicCalibrationConfig, calibrate_kinematics, read_samples
    from plugins.robot.model_file import load_robot_model

    notes: list[str] = []
    if _suffix(args.data) == ".mcap":
        rec = _recording(args.data)
        joints = read_topic(rec, args.joints_topic, JointState)
        points = read_topic(rec, args.point_topic, PoseStamped)
        samples, notes = kinematic_samples(joints, points, full_pose=args.full_pose, **_pairing(args))
    else:  # .csv or .json: the same columns (docs/kinematic_calibration.md)
        samples = read_samples(args.data)
    holdout = None
    if args.holdout:
        if args.holdout.suffix.lower() not in (".csv", ".json"):
            raise CalibrationInputError(f"{args.holdout}: held-out samples are .csv or .json")
        holdout = read_samples(args.holdout)
    try:
        model = load_robot_model(args.model)
    except (OSError, KeyError) as exc:
        raise CalibrationInputError(f"robot model {args.model!r}: {exc}") from None
    if args.tool_mm:
        model = model.with_tool(T_from_Rt(np.eye(3), np.asarray(args.tool_mm) * 1e-3))
    need = min_kinematic_samples(model.dof, samples.full_pose)
    if samples.n_samples < need:
        raise CalibrationInputError(
            f"{samples.n_samples} samples: a {model.dof}-joint {'pose' if samples.full_pose else 'position'} "
            f"calibration needs at least {need} (more equations than unknowns); 3-5x that is recommended"
        )
    if not (0.0 <= args.holdout_fraction < 1.0):
        raise CalibrationInputError("--holdout-fraction must be in [0, 1)")
    config = KinematicCalibrationConfig(
        parameterisation=args.parameterisation,
        noise_position_m=args.noise_mm * 1e-3,
        noise_rotation_rad=float(np.radians(args.noise_deg)),
        trust_noise=args.trust_noise,
        holdout_fraction=args.holdout_fraction,
    )
    cal = calibrate_kinematics(model, samples, holdout=holdout, config=config)
    text, sections = kinematic_table(cal)
    return Outcome(cal.result, notes, text, sections, lambda d: write_kinematic_files(cal, d))


# --------------------------------------------------------------------------- camera intrinsics


def _intrinsics_options(p: argparse.ArgumentParser) -> None:
    from plugins.calibration.boards.cli import intrinsics_options

    intrinsics_options(p)


def _intrinsics(args: argparse.Namespace) -> Outcome:
    from plugins.calibration.boards.cli import run_intrinsics

    return run_intrinsics(args)


# --------------------------------------------------------------------------- verbs

Runner = Callable[[argparse.Namespace], Outcome]
KINDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Runner]] = {
    "handeye": (
        "hand-eye AX=XB: T_tcp_cam (eye in hand) or T_base_cam (eye to hand); DATA may also be OpenCV YAML "
        "pose pairs (.yml, camodocal's TransformPairsInput.yml)",
        _hand_eye_options,
        _hand_eye("hand_eye"),
    ),
    "robot-world": (
        "robot-world AX=ZB: the hand-eye transform and the target (world) pose jointly",
        _hand_eye_options,
        _hand_eye("robot_world"),
    ),
    "vive-desk": ("Vive desk: T_base_desktop and T_tracker_tcp from fixture contacts", _vive_options, _vive),
    "tcp": ("TCP point on the flange (and T_cam_base) with a fixed camera", _tcp_options, _tcp),
    "kinematics": (
        "kinematic (DH/MDH/POE) calibration from joint angles and measured tool points",
        _kinematics_options,
        _kinematics,
    ),
    "intrinsics": (
        "camera intrinsics (pinhole + lens distortion) from images of a calibration board",
        _intrinsics_options,
        _intrinsics,
    ),
}
#: kinds that read images (IMAGES... positional, no recording options) instead of one DATA file
IMAGE_KINDS = frozenset({"intrinsics"})
#: kinds that take DATA or, instead, --images DIR --poses FILE --board SPEC
IMAGE_OPTION_KINDS = frozenset({"handeye", "robot-world"})

EPILOG = """\
DATA: a plain file (.json / .csv, formats in docs/calibration.md) or a vgr recording (.mcap): then
the samples come from two topics (--*-topic; the defaults match recipes/calibrate_*_sim.yaml),
paired by stamp (nearest within --max-skew-s) or by order (--pair order).
intrinsics: IMAGES... (files or folders of png / jpg / bmp) and --board SPEC instead of DATA.
handeye / robot-world: DATA, or --images DIR --poses FILE --board SPEC [--intrinsics FILE] instead, or
a recording's board images: RUN.mcap --board SPEC (--image-topic, --camera-info-topic, --robot-topic).
Exit codes: 0 usable result (verdict ok), 3 usable with a warning, 1 degenerate or failed (do not
use it), 2 bad input (missing or malformed file, NaN, mixed units, too few samples, unpaired samples)."""

BAD_INPUT = (ValueError, KeyError, OSError, RecordingError, json.JSONDecodeError)


def run_kind(args: argparse.Namespace) -> int:
    """Run one ``vgr calibrate KIND`` invocation; returns the exit code."""
    _, _, runner = KINDS[args.kind]
    data = getattr(args, "data", None)
    if args.json and data is not None and Path(args.json).resolve() == Path(data).resolve():
        print(f"bad input: --json {args.json} is the data file itself: choose another output", file=sys.stderr)
        return ExitCode.INVALID
    try:
        if args.report:  # refused before the work, not after it: the folder must be new or empty
            args.report = run_folder.new_folder(args.report, "--report")
        outcome = runner(args)
    except KeyError as exc:  # a field missing in a JSON file
        print(f"bad input: {data}: missing field {exc}", file=sys.stderr)
        return ExitCode.INVALID
    except BAD_INPUT as exc:
        print(f"bad input: {exc}", file=sys.stderr)
        return ExitCode.INVALID
    result = outcome.result
    text = format_result(result, per_sample=not args.no_samples)
    if outcome.extra_text:
        text += "\n" + outcome.extra_text
    if outcome.notes:
        text = "\n".join(f"note: {n}" for n in outcome.notes) + "\n" + text
    print(text)
    if args.json:
        out = Path(args.json)
        if out.exists() and not result.usable:  # a calibration_file stage may load it: keep the working one
            out = out.with_name(f"{out.stem}.unusable{out.suffix}")
            print(f"note: kept {args.json} (this result is not usable); wrote it to {out}")
        replace_text(out, result.to_json(indent=1) + "\n")
    if args.report:
        d = write_report_dir(args.report, result, text, outcome.sections)
        if outcome.write_files is not None:
            outcome.write_files(d)
        print(f"report: {d}")
    if not result.usable:
        return ExitCode.NOT_OK
    return ExitCode.REVIEW if result.verdict == "warning" else ExitCode.OK


def _add_kinds(parser: argparse.ArgumentParser) -> None:
    kinds = parser.add_subparsers(dest="kind", required=True, metavar="KIND")
    for name, (summary, add_options, _) in KINDS.items():
        k = kinds.add_parser(
            name, help=summary, description=summary, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
        )
        if name in IMAGE_KINDS:
            k.add_argument("images", type=Path, nargs="+", help="images of the board (files or folders)")
        else:
            k.add_argument(
                "data",
                type=Path,
                nargs="?" if name in IMAGE_OPTION_KINDS else None,
                help="samples: .json / .csv (documented formats) or a vgr .mcap recording"
                + (" (or --images DIR --poses FILE --board SPEC)" if name in IMAGE_OPTION_KINDS else ""),
            )
        add_options(k)
        k.add_argument("--report", type=Path, metavar="DIR", help="write result.json, report.txt, summary.md (+ plots)")
        k.add_argument("--json", type=Path, metavar="OUT", help="write the CalibrationResult as JSON")
        k.add_argument("--no-samples", action="store_true", help="leave the per-sample table out of the report")
        if name not in IMAGE_KINDS:
            k.add_argument("--pair", choices=["stamp", "order"], default="stamp", help="MCAP: how samples are paired")
            k.add_argument(
                "--max-skew-s", type=float, default=0.05, help="MCAP: largest stamp difference within a pair"
            )
            k.add_argument("--drop-unmatched", action="store_true", help="MCAP: drop samples without a partner")
        k.set_defaults(func=run_kind)


def add_verbs(sub: argparse._SubParsersAction) -> None:
    """Add ``vgr calibrate`` to the vgr command line."""
    p = sub.add_parser(
        "calibrate",
        help="calibrate from a sample file, a recording or images (handeye, robot-world, vive-desk, tcp, kinematics, "
        "intrinsics)",
        description="Calibrate from a sample file or a vgr recording; `vgr calibrate KIND --help` for each kind.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_kinds(p)


def main(argv: list[str] | None = None) -> int:
    """``python -m plugins.calibration.cli KIND DATA ...`` (the same as ``vgr calibrate``)."""
    parser = ArgumentParser(
        prog="vgr calibrate",
        description="Every calibration of vgr from a plain file or a vgr recording.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_kinds(parser)
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
