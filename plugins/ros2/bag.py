"""``vgr bag import`` / ``vgr bag export``: rosbag2 <-> vgr recordings (a verb module of engine.cli.main).

    vgr bag import BAG -o FILE.mcap [--recipe RECIPE [-p KEY=VALUE]] [--topic /ros/topic=stage/port] [--frame ROS=VGR]
    vgr bag export RUN.mcap -o DIR [--topic stage/port=/ros/topic] [--frame ROS=VGR]

BAG is a rosbag2 folder (MCAP or sqlite3 storage, CDR) or one of its ``.mcap`` / ``.db3`` files;
DIR a new rosbag2 folder (MCAP storage). What goes where and what is skipped:
plugins.ros2.bag_import and plugins.ros2.bag_export, docs/ros2.md. Both print a summary (topics,
counts, what was skipped and why) or, with ``--json``, one document (``vgr.bag_import/1``,
``vgr.bag_export/1``; engine/cli/schemas), ``vgr.invalid/1`` on invalid input. Exit codes
(engine.exit_codes): 0 written, 1 nothing in the input converts (nothing written), 2 invalid input
(no such file, an output that exists, a bad option, a broken bag, the ``ros2`` extra missing).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from engine.exit_codes import ExitCode

IMPORT_FORMAT = "vgr.bag_import/1"
EXPORT_FORMAT = "vgr.bag_export/1"

out = Console(width=None if sys.stdout.isatty() else 160)


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "bag",
        help="import a rosbag2 as a vgr recording, export a recording as a rosbag2",
        description="rosbag2 <-> vgr recordings with ROS 2 standard messages (docs/ros2.md; the ros2 extra).",
        epilog="exit codes: 0 written, 1 nothing in the input converts (nothing written), 2 invalid input",
    )
    verbs = p.add_subparsers(dest="bag_verb", required=True)
    i = verbs.add_parser("import", help="a rosbag2 (MCAP or sqlite3, CDR) -> a new vgr recording")
    i.add_argument("bag", help="rosbag2 folder, or one .mcap / .db3 file of one")
    i.add_argument("-o", "--output", required=True, metavar="FILE.mcap", help="the new vgr recording (never replaced)")
    i.add_argument("--recipe", help="the recipe whose stages the recording feeds on replay (vgr replay FILE)")
    i.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="override a recipe parameter")
    i.add_argument(
        "--topic",
        action="append",
        metavar="ROS_TOPIC=STAGE/PORT",
        help="put a ROS topic on this vgr stage's port (default: the recipe's ros2_subscribe port of the topic, "
        "else its only port of the type, else the topic's own name)",
    )
    _frame_option(i)
    i.add_argument("--json", action="store_true", help="print the outcome as one JSON document")
    i.set_defaults(func=cmd_import)
    e = verbs.add_parser("export", help="a vgr recording -> a new rosbag2 folder (MCAP storage, CDR)")
    e.add_argument("recording", help="vgr recording (.mcap)")
    e.add_argument("-o", "--output", required=True, metavar="DIR", help="the new rosbag2 folder (never replaced)")
    e.add_argument(
        "--topic",
        action="append",
        metavar="STAGE/PORT=ROS_TOPIC",
        help="write a vgr channel on this ROS topic (default: the same name, /stage/port); e.g. robot/frames=/tf",
    )
    _frame_option(e)
    e.add_argument("--json", action="store_true", help="print the outcome as one JSON document")
    e.set_defaults(func=cmd_export)


def _frame_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--frame",
        action="append",
        metavar="ROS_FRAME=VGR_FRAME",
        help="map a ROS frame id to a vgr frame name (and back on export); others keep their names",
    )
    p.add_argument("--strict-frames", action="store_true", help="refuse a frame that no --frame names")


def pairs(values: list[str] | None, option: str) -> dict[str, str]:
    """``A=B`` values of *option* as a dict (ValueError naming the bad one)."""
    result: dict[str, str] = {}
    for v in values or []:
        key, sep, value = v.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ValueError(f"{option} {v!r}: write {option} FROM=TO")
        result[key.strip()] = value.strip()
    return result


def _frames(args: argparse.Namespace) -> Any:
    from plugins.ros2.convert import FrameMap

    return FrameMap(pairs(args.frame, "--frame"), strict=args.strict_frames)


def _needs_rosbags() -> None:
    from plugins.ros2.convert_common import MissingExtraError, typestore

    try:
        typestore()
    except MissingExtraError as exc:
        raise ValueError(str(exc)) from None


def _document(
    fmt: str, verb: str, where: dict[str, Any], report: Any, **counts: int
) -> tuple[dict[str, Any], ExitCode]:
    """The ``--json`` document of an import or export (the README's schema) and its exit code:
    ok when anything was written, else empty (exit 1)."""
    code = ExitCode.OK if report.messages_written else ExitCode.NOT_OK
    doc = {
        "format": fmt,
        "verb": verb,
        "ok": code == ExitCode.OK,
        "outcome": "ok" if code == ExitCode.OK else "empty",
        "exit_code": int(code),
        **where,
        "messages_written": report.messages_written,
        **counts,
        "topics": [vars(t) for t in report.topics],
        "skipped": report.skipped,
        "notes": report.notes,
    }
    return doc, code


def cmd_import(args: argparse.Namespace) -> int:
    _needs_rosbags()
    from plugins.ros2.bag_import import NothingToImportError, import_bag

    try:
        report = import_bag(
            args.bag,
            args.output,
            topics=pairs(args.topic, "--topic"),
            recipe=args.recipe,
            overrides=args.param or [],
            frames=_frames(args),
        )
    except NothingToImportError as exc:
        return _nothing(args, "bag import", str(exc), exc.skipped)
    where = {"bag": report.bag, "output": report.output, "storage": report.storage, "recipe": report.recipe}
    doc, code = _document(IMPORT_FORMAT, "bag import", where, report, deliveries=report.deliveries)
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        return code
    rows = [(t.ros_topic, t.ros_type, t.vgr_topic, str(t.messages), ", ".join(t.fed) or "-") for t in report.topics]
    _print(f"imported {report.bag} ({report.storage})", ("ROS topic", "ROS type", "vgr topic", "messages", "read by"),
           rows, report.skipped, report.notes)  # fmt: skip
    out.print(
        f"{report.messages_written} messages, {report.deliveries} deliveries: {escape(report.output)}"
        + ("" if report.recipe else " (no --recipe: data only)"),
        highlight=False,
        soft_wrap=True,
    )
    return code


def cmd_export(args: argparse.Namespace) -> int:
    _needs_rosbags()
    from plugins.ros2.bag_export import NothingToExportError, export_bag

    try:
        report = export_bag(args.recording, args.output, topics=pairs(args.topic, "--topic"), frames=_frames(args))
    except NothingToExportError as exc:
        return _nothing(args, "bag export", str(exc), exc.skipped)
    where = {"recording": report.recording, "output": report.output, "storage": "mcap"}
    doc, code = _document(EXPORT_FORMAT, "bag export", where, report)
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        return code
    rows = [(t.vgr_topic, t.vgr_type, t.ros_topic, t.ros_type, str(t.messages)) for t in report.topics]
    _print(f"exported {report.recording}", ("vgr topic", "vgr type", "ROS topic", "ROS type", "messages"), rows,
           report.skipped, report.notes)  # fmt: skip
    out.print(f"{report.messages_written} messages: rosbag2 {escape(report.output)}", highlight=False, soft_wrap=True)
    return code


def _nothing(args: argparse.Namespace, verb: str, error: str, skipped: list[dict[str, str]]) -> int:
    """Nothing in the input converts: exit 1, nothing written, the skipped topics said."""
    if args.json:
        fmt = IMPORT_FORMAT if verb == "bag import" else EXPORT_FORMAT
        doc = {"format": fmt, "verb": verb, "ok": False, "outcome": "empty", "exit_code": int(ExitCode.NOT_OK),
               "error": error, "messages_written": 0, "topics": [], "skipped": skipped, "notes": []}  # fmt: skip
        print(json.dumps(doc, allow_nan=False))
        return ExitCode.NOT_OK
    _print(verb, (), [], skipped, [])
    out.print(f"[red]nothing written[/]: {escape(error)}", highlight=False, soft_wrap=True)
    return ExitCode.NOT_OK


def _print(
    title: str,
    columns: tuple[str, ...],
    rows: Sequence[tuple[str, ...]],
    skipped: list[dict[str, str]],
    notes: list[str],
) -> None:
    if rows:
        t = Table(title=escape(title), title_justify="left")
        for c in columns:
            t.add_column(c, overflow="fold", justify="right" if c == "messages" else "left")
        for r in rows:
            t.add_row(*(escape(v) for v in r))
        out.print(t)
    for s in skipped:
        out.print(f"[yellow]skipped[/] {escape(s['topic'])} ({escape(s['type'])}): {escape(s['reason'])}",
                  highlight=False, soft_wrap=True)  # fmt: skip
    for n in notes:
        out.print(f"[yellow]note[/] {escape(n)}", highlight=False, soft_wrap=True)
