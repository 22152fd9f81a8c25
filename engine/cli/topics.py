"""CLI verbs on the live bus: ``vgr topics list|echo|hz`` (engine.recording.topics) and ``vgr play``
(engine.recording.play).

Exit codes: 0 done; 1 ``echo`` got no message before its timeout; 2 bad input: no run found, several
runs and no ``--run-id``, no such topic, a recording that cannot be played; 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from engine.cli.arguments import add_listen_option
from engine.exit_codes import ExitCode

out = Console(width=None if sys.stdout.isatty() else 160)
err = Console(stderr=True)


def cmd_topics(args: argparse.Namespace) -> int:
    from engine.recording.topics import choose_run, echo, hz, open_client
    from engine.transport.endpoints import run_sockets

    with open_client(list(args.connect or run_sockets()), args.certs, args.identity) as bus:
        run = choose_run(bus, args.run_id, args.discovery_timeout)
        if args.action == "list":
            return _print_list(run, args.json)
        if args.action == "echo":
            n = 0
            for doc in echo(bus, run, args.topic, args.count, args.timeout):
                print(json.dumps(doc) if args.json else json.dumps(doc, indent=2), flush=True)
                n += 1
            if n == 0:
                err.print(f"no message on {', '.join(args.topic)} within {args.timeout:g} s", highlight=False)
                return ExitCode.NOT_OK
            return ExitCode.OK
        for window in hz(bus, run, args.topic, args.window, args.windows):
            for r in window:
                if args.json:
                    print(json.dumps(vars(r)), flush=True)
                elif r.rate_hz is None:
                    out.print(f"{r.topic}: {r.messages} message(s) in {r.window_s:g} s", highlight=False)
                else:
                    out.print(
                        f"{r.topic}: {r.rate_hz:.2f} Hz over {r.messages} messages; gaps mean {r.gap_mean_ms:.1f} ms, "
                        f"min {r.gap_min_ms:.1f}, max {r.gap_max_ms:.1f}, std {r.gap_std_ms:.1f}",
                        highlight=False,
                    )
        return ExitCode.OK


def _print_list(run: Any, as_json: bool) -> int:
    if as_json:
        print(json.dumps({"run_id": run.run_id, "topics": run.topics}, indent=2))
        return ExitCode.OK
    sources = sorted({str(d.get("source", "run")) for d in run.docs})
    t = Table(title=f"run {run.run_id} ({', '.join(sources)})", title_justify="left")
    for col in ("topic", "type", "schema", "stage", "process", "key"):
        t.add_column(col)
    for tp in run.topics:
        t.add_row(*(escape(str(tp[c])) for c in ("topic", "type", "schema", "stage", "process", "key")))
    out.print(t)
    return ExitCode.OK


def play_document(
    run_id: str, played: int, topics: list[str], rate: float, listen: list[str], code: ExitCode
) -> dict[str, Any]:
    """``vgr play --json``'s document (engine/cli/schemas/play.schema.json)."""
    outcome = "interrupted" if code == ExitCode.INTERRUPTED else "ok"
    return {
        "format": "vgr.play/1",
        "verb": "play",
        "ok": code == ExitCode.OK,
        "outcome": outcome,
        "exit_code": int(code),
        "run_id": run_id,
        "messages_played": played,
        "topics": topics,
        "rate": rate,
        "listen": listen,
    }


def cmd_play(args: argparse.Namespace) -> int:
    from engine.recipe.endpoint_syntax import PRIVATE
    from engine.recipe.model import ZenohSettings
    from engine.recording.play import PROCESS, Player, Selection, load_recorded_types, select
    from engine.recording.reader import load
    from engine.run.sigint import on_stop_signals
    from engine.transport.bus import Bus
    from engine.transport.endpoints import private_socket, run_sockets

    rec = load(args.file)
    load_recorded_types(rec)
    msgs = select(rec, Selection(args.topics, args.start, args.end))
    run_id = args.run_id or rec.metadata.get("vgr.run", {}).get("run_id") or Path(args.file).stem
    live = run_sockets(run_id)
    if args.run_id is None and live:  # a run (or a play) of that id listens on this host
        raise ValueError(f"run {run_id!r} listens on this host ({live[0]}): play under another id with --run-id")
    listen = [private_socket(run_id, PROCESS) if e == PRIVATE else e for e in (args.listen or [PRIVATE])]
    with Bus(ZenohSettings(listen=listen, connect=list(args.connect or []))) as bus:
        player = Player(bus, run_id, msgs, args.rate)
        with on_stop_signals(lambda *_: player.stop()):
            topics = sorted({m.topic for m in msgs})
            err.print(
                f"playing {len(msgs)} messages of {len(topics)} topic(s) as run {run_id} at {args.rate:g}x "
                f"on {', '.join(listen) or 'no listener'}",
                highlight=False,
            )
            if args.wait_subscribers and not player.wait_for_subscribers(args.wait_subscribers):
                err.print(f"not every topic had a subscriber after {args.wait_subscribers:g} s; playing anyway")
            n = player.play(args.loop)
    code = ExitCode.INTERRUPTED if player.stopped else ExitCode.OK
    if args.json:
        print(json.dumps(play_document(run_id, n, topics, args.rate, listen, code)))
    else:
        out.print(f"played {n} messages", highlight=False)
    return code


def _add_connect_option(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument(
        "--connect", action="append", metavar="ENDPOINT", help=f"zenoh endpoint to connect to (repeatable; {default})"
    )


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("topics", help="list, echo or time the topics of a running run (like ros2 topic)")
    acts = p.add_subparsers(dest="action", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--run-id", help="the run to look at (default: the only one running)")
    common.add_argument("--json", action="store_true", help="JSON output (one object per line for echo and hz)")
    common.add_argument("--discovery-timeout", type=float, default=2.0, metavar="S", help="seconds to find runs")
    _add_connect_option(common, "default: the private sockets of this user's runs on this host")
    common.add_argument(
        "--certs", metavar="DIR", help="a secured run: folder with ca.pem and the observer's certificate"
    )
    common.add_argument("--identity", metavar="NAME", help="with --certs: the observer (its NAME.pem / NAME.key)")
    a = acts.add_parser("list", parents=[common], help="topics with their message type, schema and stage")
    a = acts.add_parser("echo", parents=[common], help="print decoded messages of topics")
    a.add_argument("topic", nargs="+", help="topic: /stage/port (or stage.port)")
    a.add_argument("--count", type=_positive_int, default=1, help="stop after N messages (default 1)")
    a.add_argument("--timeout", type=float, default=10.0, metavar="S", help="stop after S seconds (default 10)")
    a = acts.add_parser("hz", parents=[common], help="message rate of topics, over windows")
    a.add_argument("topic", nargs="+", help="topic: /stage/port (or stage.port)")
    a.add_argument("--window", type=float, default=2.0, metavar="S", help="window length in seconds (default 2)")
    a.add_argument("--windows", type=_positive_int, default=1, help="windows to measure (default 1)")
    p.set_defaults(func=cmd_topics)

    p = sub.add_parser(
        "play", help="put a recording's topics back on zenoh at their recorded pace (like ros2 bag play)"
    )
    p.add_argument("file", help="recording (.mcap)")
    p.add_argument("--rate", type=float, default=1.0, help="factor of the recorded pace (default 1; 2 = twice as fast)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics (/stage/port)")
    p.add_argument(
        "--loop", nargs="?", type=int, const=0, default=1, metavar="N", help="play N times (no N: until Ctrl-C)"
    )
    p.add_argument("--start", type=float, metavar="S", help="from S seconds after the recording's first message")
    p.add_argument("--end", type=float, metavar="S", help="to S seconds after the recording's first message")
    p.add_argument("--run-id", help="run id of the keys played on (default: the recorded run's)")
    add_listen_option(p, "private")
    p.add_argument(
        "--wait-subscribers", type=float, default=0.0, metavar="S",
        help="wait up to S seconds for a subscriber on every played topic before the first message (default 0)",
    )  # fmt: skip
    _add_connect_option(p, "default: none")
    p.add_argument("--json", action="store_true", help="print the outcome as one JSON document (vgr.play/1)")
    p.set_defaults(func=cmd_play)


def _positive_int(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text}: must be 1 or more")
    return n
