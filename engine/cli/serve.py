"""``vgr serve RECIPE`` (a recipe as a cell service) and ``vgr call CELL COMMAND`` (its client).

``vgr serve`` sets the recipe's stages up once and answers the controller API of its ``serve.cell``
(engine.run.cell) until Ctrl-C, SIGTERM or a ``stop`` request; it listens on the cell's private
socket (this user, this host) unless the recipe or ``--listen`` says more, and starts the
gateways its ``serve.gateways`` names. Its run folder holds ``cycles.jsonl`` (one line per cycle:
time, number, command, id, status, timing) and ``cycles/`` (the rolling recordings). Exit: 0 after
an orderly stop, 130 when a stop cut a cycle short (motion halted first), 4 when a stage failed or a
process was lost, 2 on an invalid recipe.

``vgr call`` sends one request and prints the reply (``--json``: the reply document as it came); its
exit code follows the reply's status: 0 ok; 1 a no for this part (no_part, ambiguous, out_of_limits,
not_converged, busy, stopping); 2 an invalid request or pose; 4 a fault (camera_fault, fault, or no
cell answering).
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape

from engine import run_folder
from engine.cli.arguments import add_listen_option
from engine.cli.recording import add_runs_dir_option
from engine.errors import RecipeError
from engine.exit_codes import ExitCode

console = Console(stderr=True)
out = Console()

CALL_EXIT_CODES: dict[str, ExitCode] = {
    "ok": ExitCode.OK,
    "no_part": ExitCode.NOT_OK,
    "ambiguous": ExitCode.NOT_OK,
    "out_of_limits": ExitCode.NOT_OK,
    "not_converged": ExitCode.NOT_OK,
    "busy": ExitCode.NOT_OK,
    "stopping": ExitCode.NOT_OK,
    "invalid_request": ExitCode.INVALID,
    "robot_pose_invalid": ExitCode.INVALID,
    "camera_fault": ExitCode.FAILED,
    "fault": ExitCode.FAILED,
}


# --------------------------------------------------------------------------- serve
def cmd_serve(args: argparse.Namespace) -> int:
    from engine.cli.main import _load_graph, _security_refused
    from engine.recipe.model import ProcessSettings
    from engine.run.cell.settings import serve_problems
    from engine.run.runner import Runner

    graph, registry = _load_graph(args, check_inputs=True)
    problems = serve_problems(graph)
    if problems:
        raise RecipeError(problems)
    recipe = graph.recipe
    serve = recipe.serve
    assert serve is not None
    if args.cell:
        from engine.recipe.model import NAME_RE

        if not NAME_RE.match(args.cell):
            raise ValueError(f"--cell {args.cell!r}: letters, digits, '_' and '-', starting with a letter (max 64)")
        serve = recipe.serve = serve.model_copy(update={"cell": args.cell})
    over = recipe.processes.get(args.process) or ProcessSettings()
    listen = args.listen or over.listen or ["private"]  # the cell's socket: `vgr call <cell>` finds it
    recipe.processes[args.process] = ProcessSettings(listen=listen, connect=args.connect or over.connect)
    if _security_refused(graph, args.certs):
        return ExitCode.INVALID
    if args.process != "main":
        return _serve_member(args, graph, serve.cell)
    runner = Runner(
        graph,
        certs_dir=args.certs,
        run_id=serve.cell,
        ready_timeout_s=args.ready_timeout,
        freeze_gc=args.own_process,
        hold_open=True,
    )
    run_dir = runner.run_dir = run_folder.create(args.runs_dir, run_folder.run_name(serve.cell, "main"))
    run_folder.write_recipe(run_dir, graph.loaded)
    service, cycles = _service(args, runner, registry, run_dir)
    gateways = _start_gateways(serve.gateways, service)
    service.when_ready(lambda: _say_ready(serve.cell, gateways))
    with run_folder.logging_to(run_dir):
        service.start()
        summary = _serve_until_stopped(runner, service)
    for gw in gateways.values():
        gw.close()
    _remove_socket_folder(serve.cell)
    return _report(args, summary, service, run_dir, cycles)


def _remove_socket_folder(cell: str) -> None:
    """The cell's private socket folder, once the service's socket is gone (kept if anything is left)."""
    import contextlib

    from engine.transport.endpoints import private_socket_dir

    with contextlib.suppress(OSError):
        (private_socket_dir() / cell).rmdir()


def _serve_member(args: argparse.Namespace, graph: Any, cell: str) -> int:
    """Another process of a served recipe (a camera on its own host, say): its stages serve the main
    process's jobs until the service ends."""
    from engine.cli.main import print_summary, run_with_progress
    from engine.run.runner import Runner

    runner = Runner(graph, certs_dir=args.certs, process=args.process, run_id=cell, ready_timeout_s=args.ready_timeout)
    run_dir = runner.run_dir = run_folder.create(args.runs_dir, run_folder.run_name(cell, args.process))
    run_folder.write_recipe(run_dir, graph.loaded)
    with run_folder.logging_to(run_dir):
        summary = run_with_progress(runner, show=False)
    summary.artifacts["run folder"] = str(run_dir)
    if not args.json:
        print_summary(summary)
    return summary.exit_code


def _service(args: argparse.Namespace, runner: Any, registry: Any, run_dir: Path) -> tuple[Any, Any]:
    """The cell service of *runner*, its cycle log and, unless recording is off, its rolling recordings."""
    from engine.recording.cycle_files import CYCLES_FOLDER, CycleRecorder
    from engine.run.cell.reload import reloader
    from engine.run.cell.resources import open_files, rss_mb
    from engine.run.cell.service import CellService
    from engine.run.cell.settings import input_versions

    graph = runner.graph
    serve = graph.recipe.serve
    cycles = None
    if graph.recipe.record.enabled and not args.no_record:
        cycles = CycleRecorder(
            run_dir / CYCLES_FOLDER,
            graph.recipe.record,
            serve.record,
            graph.loaded,
            registry.plugins,
            lambda: input_versions(runner.graph, "main"),
        )
        runner.observers.append(cycles)
    log_file = (run_dir / "cycles.jsonl").open("x", encoding="utf-8")
    log_lock = threading.Lock()

    def on_cycle(line: dict[str, Any]) -> None:
        with log_lock:
            log_file.write(json.dumps(line) + "\n")
            log_file.flush()
        if cycles is not None:
            cycles.cycle_done(line)

    def status_extra() -> dict[str, Any]:
        files = cycles.files() if cycles is not None else []
        return {
            "versions": input_versions(runner.graph, "main"),
            "rss_mb": rss_mb(),
            "open_files": open_files(),
            "recording": {"folder": str(run_dir / CYCLES_FOLDER), "files": len(files)} if cycles else None,
            "run_folder": str(run_dir),
        }

    def swapped(loaded: Any) -> None:
        if cycles is not None:
            cycles.roll(loaded)

    service = CellService(
        runner, serve, reload=reloader(runner, registry, swapped), on_cycle=on_cycle, status_extra=status_extra
    )
    if cycles is not None:
        service.when_ready(cycles.roll)  # start.mcap ends when the service is ready: the first cycle file begins
    runner.before_shutdown.append(log_file.close)
    return service, cycles


def _start_gateways(settings: dict[str, dict[str, Any]], service: Any) -> dict[str, Any]:
    import importlib
    import logging

    from engine.plugin_manager import cell_gateways

    offered = cell_gateways()
    started: dict[str, Any] = {}
    for name, options in settings.items():
        if name not in offered:
            raise ValueError(f"serve.gateways.{name}: no such gateway (offered: {', '.join(offered) or 'none'})")
        module = importlib.import_module(offered[name])
        try:
            started[name] = module.start_gateway(service.handle, options, logging.getLogger(f"vgr.gateway.{name}"))
        except ValueError:
            for gw in started.values():
                gw.close()
            raise
    return started


def _say_ready(cell: str, gateways: dict[str, Any]) -> None:
    where = "".join(f"; {name} gateway on {gw.address[0]}:{gw.address[1]}" for name, gw in gateways.items())
    told = f"`vgr call {cell} status` from another shell{escape(where)}; Ctrl-C stops it"
    console.print(f"cell [bold]{cell}[/] ready: {told}")


def _serve_until_stopped(runner: Any, service: Any) -> Any:
    """Run in this thread (signals arrive here): a first stop signal ends the service in order, a
    second one stops the run at once (motion halted first)."""
    from engine.run.sigint import on_stop_signals, stop_reason

    def on_signal(signum: int, frame: Any) -> None:
        if service.stopping:
            signal.signal(signal.SIGINT, signal.default_int_handler)  # a third Ctrl-C interrupts hard
            runner.stop(f"{stop_reason(signum)} (second stop signal)")
        else:
            service.begin_stop(stop_reason(signum))

    with on_stop_signals(on_signal):
        try:
            return runner.run()
        except KeyboardInterrupt:
            runner.stop("interrupted (Ctrl-C)")
            raise


def _report(args: argparse.Namespace, summary: Any, service: Any, run_dir: Path, cycles: Any) -> int:
    summary.artifacts["run folder"] = str(run_dir)
    # an orderly stop releases the run (outcome ok, 0), also when some parts were refused (their alarms
    # are those cycles' answers, in cycles.jsonl: the run's "refused" is not the service's); a stop that
    # cut a cycle short, or a second stop signal, stopped it (interrupted, 130: motion halted first); a
    # failed stage or a lost process: 4
    if service.cut_short:
        code = ExitCode.INTERRUPTED
    elif summary.outcome == "refused":
        code = ExitCode.OK
    else:
        code = ExitCode(summary.exit_code)
    doc = {
        "format": "vgr.serve/1",
        "cell": service.cell,
        "exit_code": int(code),
        "outcome": "ok" if code == ExitCode.OK else summary.outcome,
        # the runner's reason when it was stopped (a cycle cut short, a second signal), else the service's
        "stop_reason": summary.stop_reason or service.stop_reason or "",
        "cycles": service.cycles,
        "by_status": service.by_status,
        "reloads": service.reloads,
        "run_folder": str(run_dir),
        "recordings": str(cycles.folder) if cycles is not None else None,
        "takt_ms": service.takt.figures().get("total", {}),
    }
    if args.json:
        print(json.dumps(doc))
    else:
        counts = ", ".join(f"{n} {s}" for s, n in sorted(service.by_status.items())) or "none"
        out.print(f"cell {service.cell}: {service.cycles} cycle(s) served ({counts}); {escape(doc['stop_reason'])}")
        out.print(f"run folder: {run_dir}")
    return int(code)


# --------------------------------------------------------------------------- call
def cmd_call(args: argparse.Namespace) -> int:
    from engine.run.cell.client import CellClient, CellUnreachableError

    try:
        request = _call_request(args)
    except ValueError as exc:
        return _call_failed(args, f"invalid request: {exc}", ExitCode.INVALID)
    try:
        with CellClient(args.cell, connect=args.connect, timeout_s=args.timeout) as cell:
            reply = cell.call(args.command, request)
    except CellUnreachableError as exc:
        return _call_failed(args, str(exc), ExitCode.FAILED)
    status = str(reply.get("status"))
    if args.json:
        print(json.dumps(reply))
    else:
        colour = "green" if status == "ok" else "red"
        out.print(f"[{colour}]{escape(status)}[/] ({reply.get('code')}): {escape(str(reply.get('message', '')))}")
        if reply.get("result"):
            out.print(json.dumps(reply["result"], indent=2), highlight=False)
    return int(CALL_EXIT_CODES.get(status, ExitCode.FAILED))


def _call_failed(args: argparse.Namespace, message: str, code: ExitCode) -> int:
    if args.json:
        print(json.dumps({"format": "vgr.call_error/1", "exit_code": int(code), "error": message}))
    else:
        console.print(f"[red]error[/]: {escape(message)}", soft_wrap=True)
    return int(code)


def _call_request(args: argparse.Namespace) -> dict[str, Any]:
    from engine.run.cell.protocol import pose_doc
    from engine.transforms import T_from_pose7

    doc: dict[str, Any] = {}
    if args.id:
        doc["id"] = args.id
    for key, values in (("pose", args.pose), ("start_pose", args.start_pose)):
        if values is not None:
            doc[key] = pose_doc(T_from_pose7(values[:3], values[3:]))
    if args.command == "locate":
        doc["count"] = args.count
    if args.command == "guide":
        if args.step is None:
            raise ValueError("guide needs --step N")
        doc["step"] = args.step
    if args.set:
        changes = {}
        for item in args.set:
            key, sep, value = item.partition("=")
            if not sep:
                raise ValueError(f"--set {item!r}: use stage.param=value")
            try:
                changes[key] = json.loads(value)
            except ValueError:  # (a bare word: the string itself)
                changes[key] = value
        doc["set"] = changes
    return doc


# --------------------------------------------------------------------------- parsers
def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from engine.cli.main import _add_recipe_args
    from engine.run.cell.protocol import COMMANDS

    p = sub.add_parser("serve", help="host a recipe as a cell service a robot controller drives")
    _add_recipe_args(p)
    p.add_argument("--process", default="main", help="the recipe's process to run here (default main: the service)")
    p.add_argument("--cell", help="the cell's name (default: the recipe's serve.cell)")
    add_listen_option(p, "private: the cell's unix socket, this user only")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="zenoh endpoint to connect to")
    p.add_argument("--certs", metavar="DIR", help="certificate folder of the recipe's security: block")
    p.add_argument("--ready-timeout", type=float, default=15.0, help="seconds to wait for the other processes")
    p.add_argument("--no-record", action="store_true", help="no cycle recordings (the cycle log is kept)")
    p.add_argument("--json", action="store_true", help="print the end-of-service summary as JSON")
    add_runs_dir_option(p, "the service's folder")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("call", help="send one request to a cell service and print its reply")
    p.add_argument("cell", help="the cell's name (its recipe's serve.cell)")
    p.add_argument("command", choices=COMMANDS)
    p.add_argument("--id", help="request id (default: a fresh one); the same id again is answered again")
    p.add_argument(
        "--pose",
        type=float,
        nargs=7,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="the robot's flange pose T_base_tcp: metres and a unit quaternion",
    )
    p.add_argument(
        "--start-pose",
        type=float,
        nargs=7,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="guide: the pose of step 0",
    )
    p.add_argument("--count", type=int, default=1, help="locate: how many parts to find in one capture")
    p.add_argument("--step", type=int, help="guide: the step number (0 = the first look)")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="reload: a parameter's new value")
    p.add_argument(
        "--connect", action="append", metavar="ENDPOINT", help="the cell's zenoh endpoint (default: its private socket)"
    )
    p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the reply")
    p.add_argument("--json", action="store_true", help="print the reply document as JSON")
    p.set_defaults(func=cmd_call)
