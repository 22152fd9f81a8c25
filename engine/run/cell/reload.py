"""A cell service's ``reload``: new parameters or re-read files, taking effect between two cycles.

:func:`reloader` returns the function :class:`~engine.run.cell.service.CellService` calls with a
request's ``set`` (``{"stage.param": value}``). It builds the recipe in effect (its text, the
overrides so far and these), checks it (every problem a ``vgr validate`` would find, the input files
exist, the same stages with the same wiring), then builds and sets up a new instance of each stage
to change, on the runtime the old one runs in, while cycles go on with the old ones. Only then does
it return the swap, which the service makes under its cycle lock: all the new stages at once, the
old ones torn down after. Anything wrong before the swap raises ValueError and changes nothing.

Which stages: with ``set``, those whose parameters change; without, every stage that reads a file
(templates, calibrations), so files replaced on disk are read again. Sources, sensors and devices
are never rebuilt (their connection is the cell's; a change to them needs a restart).
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable
from typing import Any

from engine.graph import Graph, build_graph, input_files, missing_input_files
from engine.plugin_manager import Registry
from engine.recipe.model import LoadedRecipe, load_recipe
from engine.run.runner import Runner
from engine.stage import PLAYBACK_ROLES, Stage

Swap = Callable[[], None]


def reloader(
    runner: Runner, registry: Registry, on_swapped: Callable[[LoadedRecipe], None]
) -> Callable[[dict[str, Any]], tuple[str, Swap]]:
    """The reload function of *runner*'s service; *on_swapped* sees the recipe now in effect."""

    def reload(changes: dict[str, Any]) -> tuple[str, Swap]:
        current = runner.graph.loaded
        overrides = [*current.overrides, *(f"{key}={json.dumps(value)}" for key, value in changes.items())]
        loaded = load_recipe(current.file or current.recipe.name, overrides, text=current.text)
        graph = build_graph(loaded, registry)
        missing = missing_input_files(graph, [runner.process])
        if missing:
            raise ValueError("; ".join(str(p) for p in missing))
        names = _to_rebuild(runner, graph, bool(changes))
        if not names:
            return "nothing to change", lambda: on_swapped(loaded)
        built: dict[str, Stage] = {}
        try:
            for name in names:
                node = graph.nodes[name]
                stage = node.cls(runner.runtimes[name], node.params)
                built[name] = stage
                stage.setup()
        except Exception as exc:
            for stage in built.values():
                _quiet_teardown(stage)
            raise ValueError(f"stage {name!r} could not be set up: {type(exc).__name__}: {exc}") from None

        def swap() -> None:
            old = {}
            for name, stage in built.items():
                rt = runner.runtimes[name]
                old[name], rt.stage, rt.node = rt.stage, stage, graph.nodes[name]
            runner.graph = graph
            for stage in old.values():
                if stage is not None:
                    _quiet_teardown(stage)
            on_swapped(loaded)

        return f"{', '.join(names)} rebuilt ({len(changes)} parameter(s) set)", swap

    return reload


def _to_rebuild(runner: Runner, graph: Graph, with_changes: bool) -> list[str]:
    """The stages of this process to rebuild (ValueError if the new graph is not the same graph)."""
    old = runner.graph
    if set(graph.nodes) != set(old.nodes) or graph.edges != old.edges or graph.service_edges != old.service_edges:
        raise ValueError("a reload changes parameters only: the stages and their wiring must stay the same")
    reading = {stage for stage, _, _ in input_files(graph, [runner.process])}
    names = []
    for name in runner.runtimes:
        before, after = old.nodes[name], graph.nodes[name]
        if after.spec.type != before.spec.type:
            raise ValueError(f"stage {name!r}: its type cannot change in a reload")
        changed = after.params != before.params
        wanted = changed if with_changes else name in reading
        if not wanted:
            continue
        if after.cls.role in PLAYBACK_ROLES or after.cls.is_source():
            if changed:
                raise ValueError(f"stage {name!r} is a {after.cls.role}: its parameters change with a restart only")
            continue
        names.append(name)
    return names


def _quiet_teardown(stage: Stage) -> None:
    # (a stage that was never swapped in, or is swapped out: its errors change nothing)
    with contextlib.suppress(Exception):
        stage.teardown()
