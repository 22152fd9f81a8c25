"""CLI verbs of recordings: ``vgr replay``, ``vgr inspect``, ``vgr recover`` (and the recorder and live
view options of ``vgr run``)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from engine import run_folder
from engine.cli.json_output import REPLAY_FORMAT
from engine.exit_codes import ExitCode
from engine.graph import Graph

log = logging.getLogger("vgr.cli")

if TYPE_CHECKING:
    from engine.recording.live_view import LiveView

out = Console(width=None if sys.stdout.isatty() else 160)


def recording_path(args: argparse.Namespace, graph: Graph, run_dir: Path | None) -> Path | None:
    """Where ``vgr run`` records (None with --no-record or ``record.enabled: false``); ValueError
    when ``--record`` / ``record.path`` names a file that exists."""
    from engine.recording.recorder import resolve_path

    settings = graph.recipe.record
    if getattr(args, "no_record", False) or (not settings.enabled and not getattr(args, "record", None)):
        return None
    return resolve_path(settings, graph.recipe.name, args.process, getattr(args, "record", None), run_dir)


def add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--record", metavar="PATH", help="record to this new file, or into this folder (default: the run folder)"
    )
    p.add_argument("--no-record", action="store_true", help="do not record this run")
    add_runs_dir_option(p, "the run's folder (recording, reports, log, recipe)")
    add_view_options(p)


def add_view_options(p: argparse.ArgumentParser) -> None:
    """``--view [PORT]`` and ``--view-host HOST``: the Foxglove live view (engine.recording.live_view)."""
    from engine.recording.live_view import DEFAULT_PORT

    p.add_argument(
        "--view",
        nargs="?",
        type=int,
        const=DEFAULT_PORT,
        metavar="PORT",
        help=f"serve every topic to Foxglove over WebSocket on PORT (default {DEFAULT_PORT}; 0: any free port)",
    )
    p.add_argument(
        "--view-host", default="127.0.0.1", help="address the live view binds to (default 127.0.0.1, loopback only)"
    )
    p.add_argument(
        "--view-hold",
        action="store_true",
        help="keep the live view up after the end, with each topic's last message, until Ctrl-C",
    )
    p.add_argument(
        "--view-token-file",
        metavar="FILE",
        help="serve only viewers whose URL carries the token in FILE (?token=...); FILE must be yours, "
        "mode 600; needed for --view when the recipe has security:",
    )


MIN_TOKEN_CHARS = 16


def read_view_token(path: str) -> str:
    """The token in *path* (its first line); ValueError when the file is another user's, others may
    read or write it, or the token is shorter than MIN_TOKEN_CHARS."""
    from engine.security.tls import foreign_write_access

    file = Path(path)
    if not file.is_file():
        raise ValueError(f"--view-token-file {path}: no such file")
    problems = foreign_write_access(file)
    if file.stat().st_mode & 0o044:
        problems.append(f"{path} can be read by its group or by others (chmod 600 it)")
    if problems:
        raise ValueError(f"--view-token-file: {'; '.join(problems)}")
    token = (file.read_text(errors="replace").splitlines() or [""])[0].strip()
    if len(token) < MIN_TOKEN_CHARS:
        raise ValueError(f"--view-token-file {path}: the token must be at least {MIN_TOKEN_CHARS} characters")
    return token


def start_view(args: argparse.Namespace, console: Console, secured: bool = False) -> LiveView | None:
    """The live view ``--view`` asks for (None without it); ValueError when its port cannot be had,
    or when *secured* (the recipe has ``security:``) and no ``--view-token-file`` is given: the view
    has no authentication of its own (docs/security.md)."""
    if getattr(args, "view", None) is None:
        return None
    from engine.recording.live_view import LiveView

    if not 0 <= args.view <= 65535:
        raise ValueError(f"--view {args.view}: a port is 0..65535")
    token_file = getattr(args, "view_token_file", None)
    if secured and token_file is None:
        raise ValueError(
            "--view: the recipe has security:, and the live view would serve every topic to whoever "
            "connects; give --view-token-file FILE (a token of 16+ characters, mode 600), or watch with "
            "vgr topics and an observer certificate (docs/security.md)"
        )
    token = read_view_token(token_file) if token_file is not None else None
    view = LiveView(args.view_host, args.view, token=token)
    shown = f"{view.url}/?token=<the token in {token_file}>" if token else view.url
    console.print(f"live view: {shown} (Foxglove: Open connection, Foxglove WebSocket)", highlight=False)
    return view


def add_live_view(
    args: argparse.Namespace, observers: list[Any], console: Console, *, secured: bool
) -> LiveView | None:
    """``vgr run --view``: a :class:`~engine.recording.live_view.ViewObserver` among the run's observers; the
    view, which :func:`end_view` closes after the run (*secured*: see :func:`start_view`)."""
    view = start_view(args, console, secured=secured)
    if view is not None:
        from engine.recording.live_view import ViewObserver

        observers.append(ViewObserver(view))
    return view


SHORT_RUN_S = 10.0  # a run this short was over before a viewer could follow it


def end_view(view: LiveView | None, args: argparse.Namespace, console: Console, wall_s: float) -> None:
    """After the run (or replay): with ``--view-hold``, serve each topic's last message until Ctrl-C,
    then close; without it, say how to see a run that was over in a moment."""
    if view is None:
        return
    if not args.view_hold:
        view.close()
        if wall_s < SHORT_RUN_S:
            console.print(
                f"live view: closed with the end, {wall_s:.1f} s after the start; --view-hold keeps each topic's "
                "last message on view until Ctrl-C (a run on the simulated clock does not wait for the wall clock)",
                highlight=False,
            )
        return
    console.print(
        f"live view: the end; {view.topics_with_data} topics keep their last message on {view.url} until Ctrl-C",
        highlight=False,
    )
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        close_within(view, CLOSE_WAIT_S)


CLOSE_WAIT_S = 5.0  # Ctrl-C ends the command within this even if the view's server is slow to stop


def close_within(view: LiveView, wait_s: float) -> None:
    """Close *view* on a daemon thread and wait for it at most *wait_s*: a websocket client that does
    not answer the close handshake must not keep the command from ending after Ctrl-C."""
    closer = threading.Thread(target=view.close, name="live-view-close", daemon=True)
    closer.start()
    closer.join(wait_s)
    if closer.is_alive():
        log.warning("live view: the server did not stop within %.0f s; ending without it", wait_s)


def add_runs_dir_option(p: argparse.ArgumentParser, folder: str) -> None:
    """``--runs-dir DIR``: where ``vgr run`` / ``vgr replay`` make their new folder (engine.run_folder)."""
    p.add_argument(
        "--runs-dir", metavar="DIR", default=run_folder.DEFAULT_PARENT, help=f"make {folder} in DIR (default runs/)"
    )


def cmd_replay(args: argparse.Namespace) -> int:
    from engine.exit_codes import OUTCOME_EXIT_CODES
    from engine.recording.diff import DIFFERENT, IDENTICAL, WITHIN
    from engine.recording.replay import replay
    from engine.recording.replay_update import write_updated

    speed = None if args.speed in (None, "max") else float(args.speed)
    stages = [s for s in (args.stages or "").split(",") if s] or None
    err = Console(stderr=True)
    view = start_view(args, err)
    if view is not None:
        view.advertise_recording(args.file)  # (a file it cannot read advertises nothing: the replay says why)
    t0 = time.monotonic()
    run_dir = run_folder.create(args.runs_dir, f"replay-{Path(args.file).stem}")
    try:
        with run_folder.logging_to(run_dir):
            report, rec, graph = replay(
                args.file,
                recipe=args.recipe,
                overrides=args.param or [],
                stages=stages,
                speed=speed,
                run_dir=run_dir,
                view=view.log_typed if view is not None else None,
            )
    except BaseException:
        run_folder.remove_if_unused(run_dir)
        if view is not None:
            view.close()
        raise
    run_folder.write_recipe(run_dir, graph.loaded)
    verdicts = (*report.streams, *report.requests)
    recorded = rec.metadata.get("vgr.summary", {}).get("outcome", "")
    doc = {
        "format": REPLAY_FORMAT,
        "verb": "replay",
        "recording": str(args.file),
        "ok": report.outcome == "ok",
        "outcome": report.outcome,
        "exit_code": int(OUTCOME_EXIT_CODES[report.outcome]),
        "recorded_outcome": recorded,
        "rerun": report.rerun,
        "failures": report.failures,
        "alarms": report.alarms,
        "streams": [vars(v) for v in verdicts],
        "run_folder": str(run_dir),
    }
    (run_dir / "replay.json").write_text(json.dumps(doc, indent=2, default=str))
    if args.json:
        print(json.dumps(doc, default=str))
    else:
        t = Table(title=f"replay of {args.file}: re-ran {', '.join(report.rerun) or 'nothing'}", title_justify="left")
        for col in ("topic", "recorded", "replayed", "verdict", "first difference"):
            t.add_column(col, overflow="fold")
        colour = {IDENTICAL: "green", WITHIN: "yellow", DIFFERENT: "red"}
        for v in verdicts:
            extra = v.first_difference or (f"max |diff| {v.max_abs_diff:.3g}" if v.verdict == WITHIN else "")
            t.add_row(
                escape(v.topic),
                str(v.recorded),
                str(v.replayed),
                f"[{colour.get(v.verdict, '')}]{v.verdict}[/]",
                escape(extra),
            )
        out.print(t)
        for v in verdicts:
            if v.verdict == DIFFERENT:
                out.print(f"[red]different[/] {escape(v.first_difference)}", highlight=False, soft_wrap=True)
        for f in report.failures:
            out.print(f"[red]stage failure during replay[/]: {escape(f)}", highlight=False)
        for a in report.alarms:
            out.print(f"[red]alarm[/] {escape(a)}", highlight=False, soft_wrap=True)
        counts = {k: sum(1 for v in verdicts if v.verdict == k) for k in colour}
        out.print(f"{counts[IDENTICAL]} identical, {counts[WITHIN]} within tolerance, {counts[DIFFERENT]} different")
        out.print(f"replay folder: {escape(str(run_dir))}", highlight=False, soft_wrap=True)
        out.print(f"outcome: {report.outcome} (recorded run: {recorded or 'not recorded'})", highlight=False)
    end_view(view, args, err, time.monotonic() - t0)
    if args.update:
        changed = bool(args.recipe or args.param)
        path = write_updated(report, rec, args.file, graph.loaded.text if changed else None, graph.loaded.overrides)
        out.print(f"[yellow]golden recording rewritten[/]: {path}")
        return ExitCode.OK
    return OUTCOME_EXIT_CODES[report.outcome]


def _ns(t: int) -> str:
    return datetime.fromtimestamp(t / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def cmd_inspect(args: argparse.Namespace) -> int:
    from engine.recording.reader import inspect, load

    info = inspect(load(args.file))
    if args.json:
        print(json.dumps(info, indent=2))
        return ExitCode.OK
    run = info["run"]
    out.print(
        f"[bold]{info['path']}[/] ({info['size_bytes'] / 1e6:.2f} MB): recipe [bold]{info['recipe']}[/], "
        f"run {run.get('run_id')}, process {run.get('process')}, seed {run.get('seed')}, clock {run.get('clock')}, "
        f"started {run.get('started_utc')}, span {info['time_span_s']:.3f} s",
        highlight=False,
    )
    if info["summary"]:
        out.print(f"summary: ok={info['summary'].get('ok')} {info['summary'].get('stop_reason', '')}", highlight=False)
    t = Table(title="topics", title_justify="left")
    for col in ("topic", "type", "schema", "count", "rate Hz", "first", "last"):
        t.add_column(col, justify="right" if col in ("count", "rate Hz") else "left")
    for tp in info["topics"]:
        rate = f"{tp['rate_hz']:.1f}" if tp["rate_hz"] else "-"
        t.add_row(
            tp["topic"], tp["type"], tp["schema"], str(tp["count"]), rate, _ns(tp["first_ns"]), _ns(tp["last_ns"])
        )
    out.print(t)
    if info["service_exchanges"]:
        s = Table(title="service exchanges", title_justify="left")
        s.add_column("caller -> provider")
        s.add_column("count", justify="right")
        for k, v in info["service_exchanges"].items():
            s.add_row(k, str(v))
        out.print(s)
    v = Table(title="versions", title_justify="left")
    v.add_column("package")
    v.add_column("version")
    for k, val in info["versions"].items():
        v.add_row(k, val)
    out.print(v)
    out.print(f"deliveries recorded: {info['deliveries']}; attachments: {', '.join(info['attachments']) or 'none'}")
    return ExitCode.OK


def cmd_recover(args: argparse.Namespace) -> int:
    from engine.recording.reader import recover

    r = recover(args.file, args.output, overwrite=args.force)
    state = "complete file" if r.complete else f"truncated ({r.error or 'no footer'})"
    last = _ns(r.last_log_time) if r.last_log_time else "-"
    out.print(
        f"recovered {r.messages} records from {r.source} ({state}); last log time {last}\nwritten {r.output}",
        highlight=False,
    )
    return ExitCode.OK


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("replay", help="re-run a recording's solver/action stages and diff their outputs")
    p.add_argument("file", help="recording (.mcap)")
    p.add_argument("--recipe", help="replay with this recipe instead of the recorded one")
    p.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="override a parameter for the replay")
    p.add_argument("--stages", help="comma-separated stages to re-run (default: all but sources/sensors/devices)")
    p.add_argument("--speed", default="max", help="'max' (default) or a factor of real time, e.g. 1")
    p.add_argument("--update", action="store_true", help="rewrite the recording with the replayed outputs (new golden)")
    p.add_argument("--json", action="store_true", help="print the outcome and every stream's verdict as JSON")
    add_runs_dir_option(p, "the replay's folder (its log, recipe, verdicts and stage files)")
    add_view_options(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("inspect", help="topics, counts, rates, time span, recipe and versions of a recording")
    p.add_argument("file")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("recover", help="rebuild the index of a recording cut short (e.g. kill -9)")
    p.add_argument("file")
    p.add_argument("-o", "--output", help="output file (default FILE-recovered.mcap); never FILE itself")
    p.add_argument("--force", action="store_true", help="replace the output file if it exists")
    p.set_defaults(func=cmd_recover)
