"""zenoh access control for one process of a secured run, built from the recipe's graph.

zenoh (1.x, "Access Control" in zenoh's manual) filters the messages a session exchanges with each
remote peer: a *subject* names peers by the Common Name of their TLS certificate, a *rule* allows
message kinds on key expressions in one direction (``ingress``: from the peer, ``egress``: to it),
a *policy* gives rules to subjects; what no policy allows is denied (``default_permission:
deny``). Declarations are filtered too, so a subscriber or queryable a peer may not declare never
learns of data. Each process enforces its own list, so a peer has to get past both ends.

What process P allows towards another process Q of the run (keys under ``vgr/<run>/``, see
engine.transport.bus):

- streams along graph edges only: P puts ``_wire/<s>/<port>`` to Q when stage s runs in P and a
  stage of Q reads that port (Q declares the subscriber), and the reverse;
- services along ``uses`` only: P queries ``<s>/srv/<name>`` of Q when a stage of P uses it, and
  replies to Q's queries of its own services the same way; nobody else may declare or answer them;
- ``_control`` (the run-wide stop) between the run's processes;
- liveliness: Q may declare only its own tokens (``_ready/<its stages>``, ``_started/Q``,
  ``_active/Q``, ``_peer/Q/**``, ``_shmhost/Q/**``: it maps this host's shared memory,
  engine.transport.shm_views); any process may watch the run's tokens.

Controllers (``security.controllers``, robot controllers of a cell service, engine.run.cell) may query
the API of the cell (``vgr/<cell>/api/<command>``; the cell is the run) and see its serving token
there, on the process that serves it (``main``); nothing else of the run.

Observers (``security.observers``) may subscribe to anything of the run and watch its tokens, and
query P's description ``_info/P`` (engine.transport.discovery: its topics and schemas, read-only); they may
put, declare a queryable or a token nowhere and query nothing else. Anyone else gets nothing: no subject,
no policy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from engine.graph import Graph
from engine.transport.bus import active_key, control_key, ready_key, service_key, started_key, wire_key
from engine.transport.discovery import info_key


def _process_subject(name: str) -> str:
    return f"process {name}"


def _observer_subject(name: str) -> str:
    return f"observer {name}"


class _Rules:
    """Collects rules and policies; one rule per (subject, purpose, direction)."""

    def __init__(self) -> None:
        self.rules: list[dict[str, Any]] = []
        self.policies: list[dict[str, Any]] = []

    def allow(self, subject: str, purpose: str, flow: str, messages: list[str], keys: list[str]) -> None:
        if not keys:
            return
        rid = f"{subject}: {purpose} ({flow})"
        self.rules.append(
            {"id": rid, "messages": messages, "flows": [flow], "permission": "allow", "key_exprs": sorted(set(keys))}
        )
        self.policies.append({"id": f"policy {rid}", "rules": [rid], "subjects": [subject]})


def process_token_keys(run: str, graph: Graph, process: str) -> list[str]:
    """The liveliness tokens *process* declares in a run (engine.run.membership; its membership, epoch and
    end under ``_peer/<process>/``, engine.transport.peers; the host whose shared memory it maps,
    engine.transport.shm_views)."""
    return [
        started_key(run, process),
        active_key(run, process),
        f"vgr/{run}/_peer/{process}/**",
        f"vgr/{run}/_shmhost/{process}/**",
        *(ready_key(run, s) for s in graph.stages_in(process)),
    ]


def acl_for(
    graph: Graph, process: str, run: str, observers: Sequence[str], controllers: Sequence[str] = ()
) -> dict[str, Any]:
    """zenoh's ``access_control`` section for *process* of *graph* in run *run*."""
    mine = set(graph.stages_in(process))
    r = _Rules()
    for other in graph.processes():
        if other == process:
            continue
        subj = _process_subject(other)
        theirs = set(graph.stages_in(other))
        wire_in = [wire_key(run, e.src, e.src_port) for e in graph.edges if e.src in theirs and e.dst in mine]
        wire_out = [wire_key(run, e.src, e.src_port) for e in graph.edges if e.src in mine and e.dst in theirs]
        calls = [
            service_key(run, e.provider, e.service)
            for e in graph.service_edges
            if e.client in mine and e.provider in theirs
        ]
        serves = [
            service_key(run, e.provider, e.service)
            for e in graph.service_edges
            if e.client in theirs and e.provider in mine
        ]
        r.allow(subj, "streams in", "ingress", ["put"], wire_in)
        r.allow(subj, "streams in", "egress", ["declare_subscriber"], wire_in)
        r.allow(subj, "streams out", "egress", ["put"], wire_out)
        r.allow(subj, "streams out", "ingress", ["declare_subscriber"], wire_out)
        r.allow(subj, "services called", "egress", ["query"], calls)
        r.allow(subj, "services called", "ingress", ["declare_queryable", "reply"], calls)
        r.allow(subj, "services served", "ingress", ["query"], serves)
        r.allow(subj, "services served", "egress", ["declare_queryable", "reply"], serves)
        for flow in ("ingress", "egress"):
            r.allow(subj, "run control", flow, ["put", "declare_subscriber"], [control_key(run)])
            r.allow(
                subj,
                "watch tokens",
                flow,
                ["declare_liveliness_subscriber", "liveliness_query", "reply"],
                [f"vgr/{run}/**"],
            )
        r.allow(subj, "its tokens", "ingress", ["liveliness_token"], process_token_keys(run, graph, other))
        r.allow(subj, "my tokens", "egress", ["liveliness_token"], process_token_keys(run, graph, process))
    for name in observers:
        subj = _observer_subject(name)
        run_keys = [f"vgr/{run}/**"]
        r.allow(
            subj,
            "observe",
            "ingress",
            ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            run_keys,
        )
        r.allow(subj, "observe", "egress", ["put", "liveliness_token", "reply"], run_keys)
        # a query of every process's description (vgr/<run>/_info/*) must be allowed as written:
        # zenoh refuses a key expression wider than the rule's; this process alone answers it here
        r.allow(subj, "read the description", "ingress", ["query"], [info_key(run, "*")])
        r.allow(subj, "read the description", "egress", ["declare_queryable", "reply"], [info_key(run, process)])
    serving = graph.recipe.serve is not None and process == "main"
    for name in controllers if serving else ():
        subj = f"controller {name}"
        api = [f"vgr/{run}/api/*"]
        r.allow(subj, "call the cell", "ingress", ["query", "liveliness_query"], api)
        r.allow(subj, "call the cell", "egress", ["declare_queryable", "reply", "liveliness_token"], api)
    subjects = [{"id": _process_subject(p), "cert_common_names": [p]} for p in graph.processes() if p != process]
    subjects += [{"id": _observer_subject(o), "cert_common_names": [o]} for o in observers]
    if serving:
        subjects += [{"id": f"controller {c}", "cert_common_names": [c]} for c in controllers]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": r.rules,
        "subjects": subjects,
        "policies": r.policies,
    }
