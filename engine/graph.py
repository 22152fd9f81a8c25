"""The DAG of a recipe: stages, typed data edges and service edges, validated before anything runs.

``build_graph`` checks, and reports all at once with file/line locations:

* unknown stage types (with the nearest known type),
* parameters against each stage type's pydantic model (missing, unknown, wrong type),
* input wiring: every declared input port wired exactly once, to an existing ``stage.port``,
  whose message type is the input's type or a subclass of it,
* service wiring (``uses``): the provider exists, offers the service, request/reply types fit,
  and service calls together with data edges form no wait cycle (a deadlock risk: a publisher
  waits for its consumers when their queue is full, a caller waits for its provider),
* data cycles (the closed guidance loop lives inside one action stage, so the DAG stays acyclic),
* ground truth (``truth/...`` ports of simulated stages) wired into a solver or action stage.
"""

from __future__ import annotations

import graphlib
import itertools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from engine.errors import Problem, RecipeError, nearest
from engine.messages import Message
from engine.plugin_manager import Registry
from engine.recipe.model import LoadedRecipe, StageSpec, pydantic_problems
from engine.recipe.unit_checks import implausible_lengths
from engine.stage import INPUT_FILE_MARK, Stage, StageParams, resolve_input

TRUTH_PREFIX = "truth/"  # ports carrying simulation ground truth
TRUTH_SERVICE = "truth"  # services whose name starts with this give ground truth
TRUTH_READERS = frozenset({"sensor", "device", "sink"})


@dataclass(frozen=True)
class Edge:
    src: str
    src_port: str
    dst: str
    dst_port: str
    type: type[Message]


@dataclass(frozen=True)
class ServiceEdge:
    client: str
    client_name: str
    provider: str
    service: str


@dataclass
class StageNode:
    name: str
    spec: StageSpec
    cls: type[Stage]
    params: StageParams


@dataclass
class Graph:
    loaded: LoadedRecipe
    nodes: dict[str, StageNode]
    edges: list[Edge]
    service_edges: list[ServiceEdge]
    order: list[str] = field(default_factory=list)  # a topological order of the stages

    @property
    def recipe(self):
        return self.loaded.recipe

    def inputs_of(self, stage: str) -> list[Edge]:
        """The data edges into *stage* (an index built once: the run asks per stage and per
        recorded delivery, and a walk over every edge each time made a run quadratic in its stages)."""
        return self._index[0].get(stage, [])

    def consumers_of(self, stage: str, port: str) -> list[Edge]:
        return self._index[1].get((stage, port), [])

    @cached_property
    def _index(self) -> tuple[dict[str, list[Edge]], dict[tuple[str, str], list[Edge]]]:
        into: dict[str, list[Edge]] = {}
        out_of: dict[tuple[str, str], list[Edge]] = {}
        for e in self.edges:
            into.setdefault(e.dst, []).append(e)
            out_of.setdefault((e.src, e.src_port), []).append(e)
        return into, out_of

    def stages_in(self, process: str) -> list[str]:
        return [n for n in self.order if self.nodes[n].spec.process == process]

    def processes(self) -> list[str]:
        return sorted({n.spec.process for n in self.nodes.values()})

    def to_mermaid(self) -> str:
        lines = ["flowchart LR"]
        by_proc: dict[str, list[str]] = {}
        for name in self.order:
            by_proc.setdefault(self.nodes[name].spec.process, []).append(name)
        multi = len(by_proc) > 1
        for proc, names in by_proc.items():
            if multi:
                lines.append(f"  subgraph {proc}")
            for n in names:
                lines.append(f'  {n}["{n}<br/><i>{self.nodes[n].cls.type_name}</i>"]')
            if multi:
                lines.append("  end")
        for e in self.edges:
            lines.append(f"  {e.src} -->|{e.src_port} → {e.dst_port}: {e.type.TYPE}| {e.dst}")
        for s in self.service_edges:
            lines.append(f"  {s.client} -.->|{s.client_name} → {s.service}()| {s.provider}")
        return "\n".join(lines)

    def to_dot(self) -> str:
        lines = [f'digraph "{self.recipe.name}" {{', "  rankdir=LR;", "  node [shape=box];"]
        for n in self.order:
            lines.append(f'  "{n}" [label="{n}\\n({self.nodes[n].cls.type_name})"];')
        for e in self.edges:
            lines.append(f'  "{e.src}" -> "{e.dst}" [label="{e.src_port}→{e.dst_port}\\n{e.type.TYPE}"];')
        for s in self.service_edges:
            lines.append(f'  "{s.client}" -> "{s.provider}" [style=dashed, label="{s.service}()"];')
        lines.append("}")
        return "\n".join(lines)


@dataclass(frozen=True)
class _Wiring:
    """What a wiring reference ``<stage>.<what>`` names in the stage it names: an output port (a data
    input's reference) or a service (a service client's), and how problems with it are worded."""

    what: str
    offered: Callable[[type[Stage]], Mapping[str, Any]]
    missing: str  # the stage offers no such thing (format fields a, type, b, names)
    truth_prefix: str
    truth: str  # a stage of a role other than TRUTH_READERS wired to simulation ground truth


_INPUT = _Wiring(
    "port",
    lambda cls: cls.all_outputs(),
    "stage {a!r} ({type}) has no output {b!r} (outputs: {names})",
    TRUTH_PREFIX,
    "is simulation ground truth: only sensor, device and sink stages may read it",
)
_CLIENT = _Wiring(
    "service",
    lambda cls: cls.services,
    "stage {a!r} offers no service {b!r} (services: {names})",
    TRUTH_SERVICE,
    "gives simulation ground truth: only sensor, device and sink stages may call it",
)


def _wired_to(
    loaded: LoadedRecipe,
    path: tuple[str, ...],
    ref: str,
    wiring: _Wiring,
    reader: type[Stage],
    classes: dict[str, type[Stage]],
    problems: list[Problem],
) -> tuple[str, str, Any] | None:
    """``(stage, name, what the stage offers under that name)`` for the reference *ref* at *path* of
    a stage of type *reader*; None when there is a problem with it (added to *problems*, except when
    the named stage's type is unknown: that is a problem of its own)."""
    parts = ref.split(".") if isinstance(ref, str) else []
    if len(parts) != 2 or not all(parts):
        problems.append(loaded.problem(path, f"{ref!r} must be written <stage>.<{wiring.what}>"))
        return None
    a, b = parts
    if a not in loaded.recipe.stages:
        problems.append(loaded.problem(path, f"no stage named {a!r}", nearest(a, loaded.recipe.stages)))
        return None
    if a not in classes:
        return None
    offered = wiring.offered(classes[a])
    if b not in offered:
        names = ", ".join(offered) or "none"
        missing = wiring.missing.format(a=a, type=classes[a].type_name, b=b, names=names)
        problems.append(loaded.problem(path, missing, nearest(b, offered)))
        return None
    if b.startswith(wiring.truth_prefix) and reader.role not in TRUTH_READERS:
        problems.append(loaded.problem(path, f"{a}.{b} {wiring.truth}, not a {reader.role} stage"))
        return None
    return a, b, offered[b]


def build_graph(loaded: LoadedRecipe, registry: Registry) -> Graph:
    """Validate *loaded* against the plugin *registry* and return its Graph (or raise RecipeError).

    Every problem is collected before raising, in recipe order: per stage its type and parameters,
    then per stage its inputs and its service clients, then cycles."""
    problems: list[Problem] = []
    nodes, classes = _stage_nodes(loaded, registry, problems)
    edges: list[Edge] = []
    service_edges: list[ServiceEdge] = []
    for name, cls in classes.items():
        edges += _input_edges(loaded, name, cls, classes, problems)
        service_edges += _service_edges(loaded, name, cls, classes, problems)
    order: list[str] = []
    if not problems:
        order = _check_cycles(loaded, nodes, edges, service_edges, problems)
    if problems:
        raise RecipeError(problems)
    return Graph(loaded, nodes, edges, service_edges, order)


def input_files(graph: Graph, processes: Iterable[str] | None = None) -> list[tuple[str, str, Path]]:
    """``(stage, parameter, path)`` of every :func:`engine.stage.input_file` parameter that is set,
    of the stages of *processes* (None: every process); relative paths resolved from the recipe's folder."""
    path = graph.loaded.path
    recipe_dir = path.resolve().parent if path is not None and path.is_file() else None
    hosted = set(graph.processes() if processes is None else processes)
    found = []
    for name, node in graph.nodes.items():
        if node.spec.process not in hosted:
            continue
        for key, info in type(node.params).model_fields.items():
            value = getattr(node.params, key)
            marked = isinstance(info.json_schema_extra, dict) and info.json_schema_extra.get(INPUT_FILE_MARK)
            if marked and value:
                found.append((name, key, resolve_input(value, recipe_dir)))
    return found


def missing_input_files(graph: Graph, processes: Iterable[str] | None = None) -> list[Problem]:
    """A problem for each :func:`engine.stage.input_file` parameter of the stages of *processes*
    (None: every process) that names no existing file or folder."""
    problems = []
    for name, key, file in input_files(graph, processes):
        if not file.exists():
            value = getattr(graph.nodes[name].params, key)
            where = ("stages", name, "params", key)
            problems.append(graph.loaded.problem(where, f"{key} {str(value)!r}: no such file or folder ({file})"))
    return problems


def _stage_nodes(
    loaded: LoadedRecipe, registry: Registry, problems: list[Problem]
) -> tuple[dict[str, StageNode], dict[str, type[Stage]]]:
    """The stages whose type is known and whose parameters validate (nodes), and every stage whose
    type is known (classes: their wiring is checked too, so one run of ``vgr validate`` says all)."""
    nodes: dict[str, StageNode] = {}
    classes: dict[str, type[Stage]] = {}
    for name, spec in loaded.recipe.stages.items():
        cls = registry.stages.get(spec.type)
        if cls is None:
            problems.append(
                loaded.problem(
                    ("stages", name, "type"),
                    f"unknown stage type {spec.type!r}",
                    nearest(spec.type, registry.stages),
                )
            )
            continue
        classes[name] = cls
        try:
            params = cls.Params.model_validate(spec.params)
        except ValidationError as exc:
            problems.extend(
                pydantic_problems(
                    exc, cls.Params, ("stages", name, "params"), loaded.locations, loaded.file, loaded.overridden
                )
            )
            continue
        units = [
            loaded.problem(("stages", name, "params", *where), why) for where, why in implausible_lengths(spec.params)
        ]
        if units:
            problems.extend(units)
            continue
        nodes[name] = StageNode(name, spec, cls, params)
    return nodes, classes


def _undeclared(
    loaded: LoadedRecipe,
    name: str,
    section: str,
    named: Iterable[str],
    declared: Mapping[str, Any],
    message: Callable[[str], str],
) -> list[Problem]:
    """A problem for each name the recipe wires under ``stages.<name>.<section>`` that the stage's
    type does not declare (*message*: what the problem says of that name)."""
    return [
        loaded.problem(("stages", name, section, key), message(key), nearest(key, declared))
        for key in named
        if key not in declared
    ]


def _input_edges(
    loaded: LoadedRecipe, name: str, cls: type[Stage], classes: dict[str, type[Stage]], problems: list[Problem]
) -> list[Edge]:
    """The data edges into stage *name*, each checked: declared, wired, of a matching type, not a loop."""
    spec = loaded.recipe.stages[name]
    inputs = ", ".join(cls.inputs) or "none"
    problems += _undeclared(
        loaded,
        name,
        "inputs",
        spec.inputs,
        cls.inputs,
        lambda key: f"stage type {cls.type_name!r} has no input port {key!r} (inputs: {inputs})",
    )
    edges = []
    for port, in_type in cls.inputs.items():
        path = ("stages", name, "inputs", port)
        ref = spec.inputs.get(port)
        if ref is None:
            problems.append(
                loaded.problem(
                    ("stages", name, "inputs"),
                    f"input port {port!r} ({in_type.TYPE}) is not wired; add `{port}: <stage>.<port>`",
                )
            )
            continue
        wired = _wired_to(loaded, path, ref, _INPUT, cls, classes, problems)
        if wired is None:
            continue
        src, src_port, out_type = wired
        if not issubclass(out_type, in_type):
            problems.append(
                loaded.problem(
                    path,
                    f"type mismatch: {src}.{src_port} produces {out_type.TYPE}, input {port!r} needs {in_type.TYPE}",
                )
            )
        elif src == name:
            problems.append(loaded.problem(path, "a stage cannot consume its own output"))
        else:
            edges.append(Edge(src, src_port, name, port, out_type))
    return edges


def _service_edges(
    loaded: LoadedRecipe, name: str, cls: type[Stage], classes: dict[str, type[Stage]], problems: list[Problem]
) -> list[ServiceEdge]:
    """The service calls stage *name* makes, each checked: declared, wired unless optional, of a
    matching request and reply type, not to itself (it would deadlock)."""
    spec = loaded.recipe.stages[name]
    problems += _undeclared(
        loaded,
        name,
        "uses",
        spec.uses,
        cls.uses,
        lambda key: f"stage type {cls.type_name!r} uses no service called {key!r}",
    )
    edges = []
    for client, need in cls.uses.items():
        path = ("stages", name, "uses", client)
        ref = spec.uses.get(client)
        if ref is None:
            if not need.optional:
                problems.append(
                    loaded.problem(
                        ("stages", name, "uses"),
                        f"service client {client!r} ({need.request.TYPE} -> {need.reply.TYPE})"
                        " is not wired; add `" + client + ": <stage>.<service>`",
                    )
                )
            continue
        wired = _wired_to(loaded, path, ref, _CLIENT, cls, classes, problems)
        if wired is None:
            continue
        prov, svc, have = wired
        if not (issubclass(need.request, have.request) and issubclass(have.reply, need.reply)):
            problems.append(
                loaded.problem(
                    path,
                    f"service type mismatch: {prov}.{svc} takes {have.request.TYPE} -> {have.reply.TYPE}, "
                    f"client expects {need.request.TYPE} -> {need.reply.TYPE}",
                )
            )
        elif prov == name:
            problems.append(loaded.problem(path, "a stage cannot call its own service (it would deadlock)"))
        else:
            edges.append(ServiceEdge(name, client, prov, svc))
    return edges


def _check_cycles(
    loaded: LoadedRecipe,
    nodes: dict[str, StageNode],
    edges: list[Edge],
    service_edges: list[ServiceEdge],
    problems: list[Problem],
) -> list[str]:
    ts: graphlib.TopologicalSorter[str] = graphlib.TopologicalSorter({n: set() for n in nodes})
    for e in edges:
        ts.add(e.dst, e.src)
    try:
        order = list(ts.static_order())
    except graphlib.CycleError as exc:
        cycle = exc.args[1]
        first = next(e for e in edges if e.dst == cycle[1] and e.src == cycle[0]) if len(cycle) > 1 else None
        path = ("stages", first.dst, "inputs", first.dst_port) if first else ("stages",)
        problems.append(
            loaded.problem(
                path,
                "data cycle: "
                + " -> ".join(cycle)
                + " (a closed loop belongs inside one action stage that calls services)",
            )
        )
        return []
    # wait-for graph: a publisher waits for its consumers (backpressure), a caller for its provider
    wait: graphlib.TopologicalSorter[str] = graphlib.TopologicalSorter({n: set() for n in nodes})
    for e in edges:
        wait.add(e.dst, e.src)
    for s in service_edges:
        wait.add(s.provider, s.client)
    try:
        list(wait.static_order())
    except graphlib.CycleError as exc:
        cycle = exc.args[1]  # each node waits for the next one
        # point at a service call of the loop (a `uses:` entry): that is the wiring to reconsider
        call = next(
            (s for s in service_edges for a, b in itertools.pairwise(cycle) if (s.client, s.provider) == (a, b)),
            None,
        )
        path = ("stages", call.client, "uses", call.client_name) if call else ("stages", cycle[0], "uses")
        problems.append(
            loaded.problem(
                path, "service calls and data edges form a wait cycle (deadlock risk): " + " -> ".join(cycle)
            )
        )
        return []
    return order
