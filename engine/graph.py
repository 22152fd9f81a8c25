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
from dataclasses import dataclass, field

from pydantic import ValidationError

from engine.errors import Problem, RecipeError, nearest
from engine.messages import Message
from engine.plugin_manager import Registry
from engine.recipe import LoadedRecipe, StageSpec, pydantic_problems
from engine.stage import Stage, StageParams

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
        return [e for e in self.edges if e.dst == stage]

    def consumers_of(self, stage: str, port: str) -> list[Edge]:
        return [e for e in self.edges if e.src == stage and e.src_port == port]

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


def _split_ref(ref: str) -> tuple[str, str] | None:
    if not isinstance(ref, str) or ref.count(".") != 1:
        return None
    a, b = ref.split(".")
    return (a, b) if a and b else None


def build_graph(loaded: LoadedRecipe, registry: Registry) -> Graph:
    """Validate *loaded* against the plugin *registry* and return its Graph (or raise RecipeError)."""
    recipe = loaded.recipe
    problems: list[Problem] = []
    nodes: dict[str, StageNode] = {}
    classes: dict[str, type[Stage]] = {}  # stages whose type is known (their wiring is checked too)

    for name, spec in recipe.stages.items():
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
                pydantic_problems(exc, cls.Params, ("stages", name, "params"), loaded.locations, loaded.file)
            )
            continue
        nodes[name] = StageNode(name, spec, cls, params)

    edges: list[Edge] = []
    service_edges: list[ServiceEdge] = []
    for name, cls in classes.items():
        spec = recipe.stages[name]
        for port in spec.inputs:
            if port not in cls.inputs:
                problems.append(
                    loaded.problem(
                        ("stages", name, "inputs", port),
                        f"stage type {cls.type_name!r} has no input port {port!r}"
                        f" (inputs: {', '.join(cls.inputs) or 'none'})",
                        nearest(port, cls.inputs),
                    )
                )
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
            parsed = _split_ref(ref)
            if parsed is None:
                problems.append(loaded.problem(path, f"{ref!r} must be written <stage>.<port>"))
                continue
            src, src_port = parsed
            if src not in recipe.stages:
                problems.append(loaded.problem(path, f"no stage named {src!r}", nearest(src, recipe.stages)))
                continue
            if src not in classes:
                continue  # that stage already has a problem of its own
            outs = classes[src].all_outputs()
            if src_port not in outs:
                problems.append(
                    loaded.problem(
                        path,
                        f"stage {src!r} ({classes[src].type_name}) has no output "
                        f"{src_port!r} (outputs: {', '.join(outs)})",
                        nearest(src_port, outs),
                    )
                )
                continue
            if src_port.startswith(TRUTH_PREFIX) and cls.role not in TRUTH_READERS:
                problems.append(
                    loaded.problem(
                        path,
                        f"{src}.{src_port} is simulation ground truth: only sensor, "
                        f"device and sink stages may read it, not a {cls.role} stage",
                    )
                )
                continue
            out_type = outs[src_port]
            if not issubclass(out_type, in_type):
                problems.append(
                    loaded.problem(
                        path,
                        f"type mismatch: {src}.{src_port} produces {out_type.TYPE}, "
                        f"input {port!r} needs {in_type.TYPE}",
                    )
                )
                continue
            if src == name:
                problems.append(loaded.problem(path, "a stage cannot consume its own output"))
                continue
            edges.append(Edge(src, src_port, name, port, out_type))
        for client in spec.uses:
            if client not in cls.uses:
                problems.append(
                    loaded.problem(
                        ("stages", name, "uses", client),
                        f"stage type {cls.type_name!r} uses no service called {client!r}",
                        nearest(client, cls.uses),
                    )
                )
        for client, need in cls.uses.items():
            path = ("stages", name, "uses", client)
            ref = spec.uses.get(client)
            if ref is None and need.optional:
                continue
            if ref is None:
                problems.append(
                    loaded.problem(
                        ("stages", name, "uses"),
                        f"service client {client!r} ({need.request.TYPE} -> {need.reply.TYPE})"
                        " is not wired; add `" + client + ": <stage>.<service>`",
                    )
                )
                continue
            parsed = _split_ref(ref)
            if parsed is None:
                problems.append(loaded.problem(path, f"{ref!r} must be written <stage>.<service>"))
                continue
            prov, svc = parsed
            if prov not in recipe.stages:
                problems.append(loaded.problem(path, f"no stage named {prov!r}", nearest(prov, recipe.stages)))
                continue
            if prov not in classes:
                continue
            offered = classes[prov].services
            if svc not in offered:
                problems.append(
                    loaded.problem(
                        path,
                        f"stage {prov!r} offers no service {svc!r} (services: {', '.join(offered) or 'none'})",
                        nearest(svc, offered),
                    )
                )
                continue
            if svc.startswith(TRUTH_SERVICE) and cls.role not in TRUTH_READERS:
                problems.append(
                    loaded.problem(
                        path,
                        f"{prov}.{svc} gives simulation ground truth: only sensor, "
                        f"device and sink stages may call it, not a {cls.role} stage",
                    )
                )
                continue
            have = offered[svc]
            if not (issubclass(need.request, have.request) and issubclass(have.reply, need.reply)):
                problems.append(
                    loaded.problem(
                        path,
                        f"service type mismatch: {prov}.{svc} takes {have.request.TYPE} "
                        f"-> {have.reply.TYPE}, client expects {need.request.TYPE} -> "
                        f"{need.reply.TYPE}",
                    )
                )
                continue
            if prov == name:
                problems.append(loaded.problem(path, "a stage cannot call its own service (it would deadlock)"))
                continue
            service_edges.append(ServiceEdge(name, client, prov, svc))

    order: list[str] = []
    if not problems:
        order = _check_cycles(loaded, nodes, edges, service_edges, problems)
    if problems:
        raise RecipeError(problems)
    return Graph(loaded, nodes, edges, service_edges, order)


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
