"""The ``vgr`` command line: run, validate, graph, plugins, schemas (and the verbs of later modules).

Exit codes: one table for every verb, engine.exit_codes (0 ok, 1 refused / not ok, 2 invalid,
3 needs a human look, 4 failed, 130 interrupted).

Ctrl-C during ``vgr run``: the SIGINT handler only calls ``Runner.stop`` (the runner halts the
devices, cuts the waiting calls short and gives the stages 2 s, see engine.run.runner), the summary says
``run interrupted`` and the command exits 130 without a traceback; a second Ctrl-C interrupts hard.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.markup import escape
from rich.table import Table

from engine import run_folder
from engine.cli import recording as cli_recording
from engine.cli.arguments import ArgumentParser, add_listen_option, split_negative_values
from engine.cli.json_output import files_written, invalid_document, run_document, validate_document
from engine.errors import RecipeError
from engine.exit_codes import HELP_EPILOG, ExitCode
from engine.graph import Graph, build_graph, missing_input_files
from engine.plugin_manager import PluginError, Registry, load_registry, plugin_verbs
from engine.recipe.model import load_recipe
from engine.recording.reader import RecordingError
from engine.recording.replay import ReplayError
from engine.run.runner import RunError, Runner, RunSummary
from engine.run.runtime import StageStats
from engine.run.sigint import on_stop_signals, stop_reason
from engine.transport.bus import BusError

console = Console(stderr=True)
out = Console(width=None if sys.stdout.isatty() else 160)


def _load_graph(args: argparse.Namespace, check_inputs: bool = False) -> tuple[Graph, Registry]:
    """The recipe's graph; with *check_inputs*, RecipeError also when an input file (a template, a
    calibration file) of a stage of ``args.process`` (None: of any process) does not exist."""
    loaded = load_recipe(args.recipe, args.param or [])
    registry = load_registry(loaded.recipe.plugins)
    graph = build_graph(loaded, registry)
    if check_inputs:
        missing = missing_input_files(graph, None if args.process is None else [args.process])
        if missing:
            raise RecipeError(missing)
    return graph, registry


def _stats_table(stats: Sequence[StageStats], title: str) -> Table:
    t = Table(title=title, title_justify="left")
    for col in ("stage", "type", "process", "state", "in", "out", "errors", "busy ms"):
        t.add_column(col, justify="right" if col in ("in", "out", "errors", "busy ms") else "left")
    for s in stats:
        style = {"failed": "red", "stopped": "yellow", "finished": "green"}.get(s.state, "")
        t.add_row(
            s.name,
            s.type_name,
            s.process,
            f"[{style}]{s.state}[/]" if style else s.state,
            str(s.messages_in + s.requests_served),
            str(s.messages_out),
            str(s.errors),
            f"{s.busy_s * 1e3:.1f}",
        )
    return t


def print_summary(summary: RunSummary) -> None:
    out.print(_stats_table(summary.stages, f"run {summary.run_id} ({summary.process}) in {summary.wall_s:.2f} s"))
    for ev in summary.events:
        if ev.level == "result":  # a stage's report for people: its text, then the files it wrote
            out.print(f"[bold green]{ev.stage}[/]: {escape(ev.message)}", soft_wrap=True, highlight=False)
            for label, where in files_written(summary, ev):
                out.print(f"  {label}: {escape(str(where))}", highlight=False, soft_wrap=True)
            continue
        colour = "yellow" if ev.level == "warning" else "red"
        out.print(f"[{colour}]{ev.level}[/] {ev.stage}: {escape(f'[{ev.code}] {ev.message}')}", soft_wrap=True)
        if ev.traceback and ev.level in ("error", "alarm"):
            out.print(ev.traceback, markup=False, highlight=False)
    for name, path in summary.artifacts.items():
        out.print(f"{name}: {escape(path)}", highlight=False, soft_wrap=True)
    if summary.outcome == "refused":
        alarms = [ev for ev in summary.events if ev.level == "alarm"]
        out.print(f"[red]run finished, refused[/]: {len(alarms)} alarm(s), first: {escape(alarms[0].stage)}")
    elif summary.ok:
        out.print("[green]run finished[/]")
    elif summary.outcome == "interrupted":  # Ctrl-C or a stop request: the devices were halted first
        ended = "" if summary.stop_to_end_s is None else f"; the stages ended {summary.stop_to_end_s:.2f} s after it"
        out.print(f"[yellow]run interrupted[/]: {escape(summary.stop_reason or '')}{ended}", soft_wrap=True)
    else:
        out.print(f"[red]run failed[/]: {escape(summary.stop_reason or 'a stage failed')}", soft_wrap=True)


def run_with_progress(runner: Runner, show: bool) -> RunSummary:
    """Run in this thread (signals arrive here); a live table appears if the run lasts > 1 s."""
    done = threading.Event()

    def live() -> None:
        if done.wait(1.0):
            return
        with Live(
            _stats_table(runner.snapshot(), "running"), console=console, refresh_per_second=4, transient=True
        ) as lv:
            while not done.wait(0.25):
                lv.update(_stats_table(runner.snapshot(), f"running {runner.run_id}"))

    th = threading.Thread(target=live, daemon=True) if show else None
    if th:
        th.start()

    def stop_on_signal(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C interrupts hard
        runner.stop(stop_reason(signum))

    with on_stop_signals(stop_on_signal):
        try:
            return runner.run()
        finally:
            done.set()
            if th:
                th.join(1.0)


# --------------------------------------------------------------------------- verbs


def cmd_run(args: argparse.Namespace) -> int:
    graph, registry = _load_graph(args, check_inputs=True)
    recipe = graph.recipe
    if recipe.serve is not None:  # its jobs come as requests: a run of it would start, find no data and end
        raise RecipeError([graph.loaded.problem(("serve",), f"a cell service: run it with `vgr serve {args.recipe}`")])
    from engine.recipe.model import ProcessSettings

    if args.listen or args.connect:
        over = recipe.processes.get(args.process) or ProcessSettings()
        recipe.processes[args.process] = ProcessSettings(
            listen=args.listen or over.listen, connect=args.connect or over.connect
        )
    from engine.cli.recording import recording_path
    from engine.recording.recorder import Recorder

    if _security_refused(graph, args.certs):  # nothing is started with certificates that cannot work
        return ExitCode.INVALID
    runner = Runner(  # refuses a bad run id or process before anything is created
        graph,
        certs_dir=args.certs,
        process=args.process,
        run_id=args.run_id,
        ready_timeout_s=args.ready_timeout,
        freeze_gc=args.own_process,  # the command's own process (not a caller's, e.g. a test): see Runner
    )
    # the live view before the folder: a taken port is refused before anything is made
    view = cli_recording.add_live_view(args, runner.observers, console, secured=recipe.security is not None)
    # a recording the user named (--record, record.path) does not depend on the run folder: it is
    # resolved, and refused if it exists, before anything is created
    named = bool(args.record or recipe.record.path)
    path = recording_path(args, graph, None) if named else None
    run_dir = runner.run_dir = run_folder.create(args.runs_dir, run_folder.run_name(runner.run_id, args.process))
    run_folder.write_recipe(run_dir, graph.loaded)
    if not named:
        path = recording_path(args, graph, run_dir)
    if path is not None:
        runner.observers.append(Recorder(path, recipe.record, graph.loaded, registry.plugins))
    with run_folder.logging_to(run_dir):
        summary = run_with_progress(runner, show=not args.no_progress and console.is_terminal)
    summary.artifacts["run folder"] = str(run_dir)
    if args.json:
        print(json.dumps(run_document(summary)))
    else:
        print_summary(summary)
    incomplete = "recording_error" in summary.artifacts
    if incomplete:  # said even when the run was interrupted
        console.print(f"[red]the recording is incomplete[/]: {escape(summary.artifacts['recording_error'])}")
    if summary.outcome != "interrupted":  # (Ctrl-C ended the run: it ends the view too)
        cli_recording.end_view(view, args, console, summary.wall_s)
    elif view is not None:
        view.close()
    if incomplete and summary.outcome != "interrupted":
        return ExitCode.FAILED
    return summary.exit_code


def _print_invalid_json(args: argparse.Namespace, error: str, problems: Sequence[Any]) -> None:
    """With ``--json`` (a flag, not a file name), the refusal as JSON on stdout (engine.cli.json_output)."""
    if getattr(args, "json", None) is True:
        print(json.dumps(invalid_document(args.verb, error, problems)))


def _security_refused(graph: Graph, certs_dir: str | None) -> bool:
    """Print what keeps the recipe's ``security:`` block from working (engine.transport.session_config);
    True when there is anything."""
    from engine.run.runner import recipe_dir
    from engine.transport.session_config import security_problems

    problems = security_problems(graph, base=recipe_dir(graph), certs_dir=certs_dir)
    for p in problems:
        out.print(f"[red]security[/]: {p}")
    return bool(problems)


def cmd_validate(args: argparse.Namespace) -> int:
    graph, _ = _load_graph(args, check_inputs=True)
    if graph.recipe.serve is not None:  # a cell service: its commands must name job services
        from engine.run.cell.settings import serve_problems

        problems = serve_problems(graph)
        if problems:
            raise RecipeError(problems)
    if _security_refused(graph, args.certs):
        return ExitCode.INVALID
    if args.json:
        print(json.dumps(validate_document(graph.recipe.name, len(graph.nodes), graph.processes())))
        return ExitCode.OK
    out.print(
        f"[green]ok[/]: {graph.loaded.file}: recipe {graph.recipe.name!r}, {len(graph.nodes)} stages, "
        f"{len(graph.edges)} data edges, {len(graph.service_edges)} service edges, "
        f"processes: {', '.join(graph.processes())}"
    )
    return ExitCode.OK


def cmd_graph(args: argparse.Namespace) -> int:
    graph, _ = _load_graph(args)
    print(graph.to_dot() if args.format == "dot" else graph.to_mermaid())
    return ExitCode.OK


def cmd_plugins(args: argparse.Namespace) -> int:
    registry = load_registry(args.plugin or [])
    described = [registry.stages[n].describe() | {"plugin": registry.stage_origin[n]} for n in sorted(registry.stages)]
    if args.json:
        print(json.dumps(described, indent=2, default=str))
        return ExitCode.OK
    out.print(f"plugins: {', '.join(registry.plugins)}")
    for d in described:
        t = Table(
            title=f"{d['type']}  [dim]({d['role']}, plugin {d['plugin']})[/]",
            title_justify="left",
            caption=d["summary"],
            caption_justify="left",
            show_header=True,
        )
        for col in ("kind", "name", "type / default"):
            t.add_column(col)
        for kind, key in (("input", "inputs"), ("output", "outputs"), ("service", "services"), ("uses", "uses")):
            for k, v in d[key].items():
                t.add_row(kind, k, v)
        for k, v in d["params"].items():
            dflt = "required" if v["required"] else f"= {v['default']!r}"
            t.add_row(
                "param",
                k,
                f"{v['type']} {dflt}" + (f"  [dim]{v['description']}[/]" if v["description"] else ""),
            )
        out.print(t)
    return ExitCode.OK


def cmd_schemas(args: argparse.Namespace) -> int:
    from engine.messages.codec import registry
    from engine.messages.schemas import proto_text

    load_registry()
    if args.descriptor_set:
        return _write_descriptor_set(
            Path(args.descriptor_set), sorted({registry.get(n).SCHEMA for n in registry.names()})
        )
    for name in registry.names():
        cls = registry.get(name)
        print(f"// {name}: {(cls.__doc__ or '').strip().splitlines()[0]}")
        print(proto_text(cls.SCHEMA))
        print()
    return ExitCode.OK


def _write_descriptor_set(path: Path, schemas: list[str]) -> int:
    """Every schema in one ``FileDescriptorSet`` (``protoc --descriptor_set_out`` format), to a new file."""
    from google.protobuf import descriptor_pb2

    from engine.messages.schemas import descriptor_set

    merged = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()
    for name in schemas:
        for fd in descriptor_pb2.FileDescriptorSet.FromString(descriptor_set(name)).file:
            if fd.name not in seen:  # dependencies first, as each set lists them
                seen.add(fd.name)
                merged.file.append(fd)
    with path.open("xb") as f:  # a new file: never replaces one
        f.write(merged.SerializeToString())
    out.print(f"{len(schemas)} schemas in {len(merged.file)} files: {escape(str(path))}", highlight=False)
    return ExitCode.OK


# --------------------------------------------------------------------------- parser

# The engine's verbs in other modules: verb -> (module with ``add_verbs(subparsers)``, one-line help).
# A module is imported only when one of its verbs runs, so `vgr --help` and `vgr run` do not pay for
# the libraries of every capability (and a Ctrl-C right after start lands in a running engine).
# Plugins add theirs through the hook ``vgr_cli_verbs`` (engine.hookspecs), in the same lazy way.
VERB_MODULES: dict[str, tuple[str, str]] = {
    "replay": ("engine.cli.recording", "re-run a recording's solver/action stages and diff their outputs"),
    "inspect": ("engine.cli.recording", "topics, counts, rates, time span, recipe and versions of a recording"),
    "recover": ("engine.cli.recording", "rebuild the index of a recording cut short (e.g. kill -9)"),
    "topics": ("engine.cli.topics", "list, echo or time the topics of a running run (like ros2 topic)"),
    "play": ("engine.cli.topics", "put a recording's topics back on zenoh at their recorded pace (like ros2 bag play)"),
    "certs": ("engine.cli.security", "development certificates for a recipe's security: block"),
    "doctor": ("engine.cli.doctor", "check the installation and the machine, and say what to fix"),
    "serve": ("engine.cli.serve", "host a recipe as a cell service a robot controller drives"),
    "call": ("engine.cli.serve", "send one request to a cell service and print its reply (like ros2 service call)"),
}


OWN_VERBS = ("run", "validate", "graph", "plugins", "schemas")  # defined in this module


def verb_modules(taken: Iterable[str] = OWN_VERBS) -> dict[str, tuple[str, str]]:
    """Every verb defined in a module of its own, the engine's and the plugins': verb -> (module, help).
    *taken* are the verbs defined here, which no plugin may take."""
    modules = dict(VERB_MODULES)
    for v in plugin_verbs(taken=[*taken, *VERB_MODULES]).values():
        modules[v.name] = (v.module, v.help)
    return modules


def _add_recipe_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("recipe", help="recipe YAML file")
    p.add_argument(
        "-p",
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help="override: stage.param=value, vars.name=value, seed=N (repeatable)",
    )


def build_parser(verb: str | None = None) -> argparse.ArgumentParser:
    """The parser; *verb* (the one being run) has its module imported and its full options."""
    parser = ArgumentParser(prog="vgr", description="3D-vision-guided robot correction")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="verb", required=True)

    p = sub.add_parser("run", help="run a recipe")
    _add_recipe_args(p)
    p.add_argument("--process", default="main", help="which of the recipe's processes to run here (default main)")
    p.add_argument("--run-id", help="run id shared by all processes of the run (default: recipe run_id or name)")
    add_listen_option(p, "the recipe's, else none for a single-process run, private sockets between processes")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="zenoh endpoint to connect to")
    p.add_argument("--certs", metavar="DIR", help="certificate folder of the recipe's security: block (overrides it)")
    p.add_argument("--ready-timeout", type=float, default=15.0, help="seconds to wait for the other processes")
    p.add_argument("--no-progress", action="store_true", help="no live progress table")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    cli_recording.add_run_options(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("validate", help="check a recipe (types, wiring, parameters, cycles) without running it")
    _add_recipe_args(p)
    p.add_argument("--certs", metavar="DIR", help="certificate folder of the recipe's security: block (overrides it)")
    p.add_argument("--process", help="check the input files of this process's stages only (default: every process's)")
    p.add_argument("--json", action="store_true", help="print the outcome as JSON")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("graph", help="print a recipe's DAG (Mermaid or Graphviz dot)")
    _add_recipe_args(p)
    p.add_argument("--format", choices=["mermaid", "dot"], default="mermaid")
    p.set_defaults(func=cmd_graph)

    p = sub.add_parser("plugins", help="list every stage type with its ports and parameters")
    p.add_argument("--json", action="store_true")
    p.add_argument(
        "--plugin",
        action="append",
        metavar="PLUGIN",
        help="also load this plugin: an installed one's name, or a plugin file (path, or name in VGR_PLUGIN_PATH)",
    )
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("schemas", help="print the protobuf schema of every message type")
    p.add_argument(
        "--descriptor-set", metavar="FILE", help="write every schema as one FileDescriptorSet to this new file"
    )
    p.set_defaults(func=cmd_schemas)

    import importlib

    modules = verb_modules(taken=sub.choices)
    if verb in modules:
        importlib.import_module(modules[verb][0]).add_verbs(sub)
    for name, (_, text) in modules.items():
        if name not in sub.choices:  # a placeholder: listed in --help, its module loads when it runs
            sub.add_parser(name, help=text, add_help=False)
    _tell_exit_codes([parser, *sub.choices.values()])
    return parser


def _tell_exit_codes(parsers: Iterable[argparse.ArgumentParser]) -> None:
    """Every verb's ``--help`` ends with the exit-code table (engine.exit_codes), its sub-verbs' too."""
    for p in parsers:
        if p.epilog is None or "exit codes" not in p.epilog:
            p.epilog = HELP_EPILOG if p.epilog is None else f"{p.epilog}\n\n{HELP_EPILOG}"
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                _tell_exit_codes(action.choices.values())


def main(argv: Sequence[str] | None = None) -> int:
    """The ``vgr`` command; *argv* None means this process is the command's own (sys.argv)."""
    try:
        return _main(list(sys.argv[1:] if argv is None else argv), own_process=argv is None)
    except BrokenPipeError:  # `vgr graph ... | head`: the reader closed the pipe; no traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # (Python's exit flush would fail)
        return ExitCode.NOT_OK
    except KeyboardInterrupt:  # before the run started (imports, parsing): nothing to stop yet
        console.print("[yellow]interrupted (Ctrl-C) before the run started[/]")
        return ExitCode.INTERRUPTED


def _main(argv: list[str], own_process: bool = False) -> int:
    argv = split_negative_values(argv)
    verb = next((a for a in argv if not a.startswith("-")), None)
    try:
        parser = build_parser(verb)
    except PluginError as exc:  # a plugin's verbs are broken: say which, as for its stages
        console.print(f"[red]error[/]: {escape(str(exc))}", highlight=False, soft_wrap=True)
        return ExitCode.INVALID
    args = parser.parse_args(argv)
    args.own_process = own_process
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    for handler in logging.getLogger().handlers:  # the console shows *level*, whatever a run's log file takes
        if type(handler) is logging.StreamHandler:
            handler.setLevel(level)
    try:
        return int(args.func(args) or 0)
    except RecipeError as exc:
        console.print(f"[red]invalid recipe[/] ({len(exc.problems)} problem{'s' * (len(exc.problems) > 1)}):")
        for p in exc.problems:
            console.print(f"  {p}", markup=False, highlight=False, soft_wrap=True)
        _print_invalid_json(args, str(exc), exc.problems)
        return ExitCode.INVALID
    except (
        PluginError,
        RunError,
        BusError,
        FileNotFoundError,
        FileExistsError,
        PermissionError,  # (a socket folder or a file of another user, a folder others may write: said, exit 2)
        ValueError,
        RecordingError,
        ReplayError,
    ) as exc:
        console.print(f"[red]error[/]: {escape(str(exc))}", highlight=False, soft_wrap=True)
        _print_invalid_json(args, str(exc), [])
        return ExitCode.INVALID
    except KeyboardInterrupt:
        console.print("[yellow]interrupted (Ctrl-C)[/]")
        return ExitCode.INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
