"""The zenoh session of one process of a run: its endpoints, TLS and access control.

What a process gets when the recipe leaves ``zenoh.listen`` unset (the embedded default):

- a recipe in one process: no listener at all, nothing to connect to; no other session on the
  host or the network can find, read or call the run (multicast scouting is off);
- a recipe in several processes: each listens on a unix socket in a folder only its user can open
  (engine.transport.endpoints.private_socket_dir: ``<dir>/<run>/<process>.sock``) and connects to the other
  processes' sockets (zenoh keeps trying those not there yet), so the processes find each other
  with nothing configured and users other than the owner cannot reach them;
- ``listen: [private]`` (or ``vgr run --listen private``): that socket for a single process too,
  so ``vgr topics`` of the same user can watch it.

With a ``security:`` block (engine.security.tls) the endpoints are the recipe's, must be ``tls/`` or
``quic/``, and the session gets mutual TLS with the process's certificate and the access-control
list engine.transport.acl builds from the graph.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine.graph import Graph
from engine.recipe.endpoint_syntax import PRIVATE
from engine.recipe.model import ZenohSettings
from engine.security.tls import SECURE_PROTOCOLS, identity, identity_problems, insecure_endpoints, tls_entries
from engine.transport.acl import acl_for
from engine.transport.endpoints import private_socket


class SessionConfigError(ValueError):
    """The recipe's zenoh settings cannot make this process's session (said before it opens)."""


@dataclass
class SessionPlan:
    """Everything Bus needs to open one process's session."""

    settings: ZenohSettings
    extra: dict[str, Any] = field(default_factory=dict)  # zenoh config path -> value
    secured: bool = False
    # endpoint this process connects to -> the process of the run listening there (where the
    # recipe says; engine.transport.link_identity checks the sessions' claims against these)
    dialled: dict[str, str] = field(default_factory=dict)


# how a session retries an endpoint not up yet: soon and often, since a process's claim to be a
# member waits for the link to its endpoint (engine.transport.link_identity); zenoh's default backs
# off to 4 s, which a process started a moment after another would wait for
CONNECT_RETRY = {"period_init_ms": 50, "period_max_ms": 500, "period_increase_factor": 2}


def _listen_endpoints(graph: Graph, process: str, run: str) -> list[str]:
    """Where *process* of run *run* listens: the recipe's ``listen``, else (several processes, no
    ``security:``) its private socket, else nowhere."""
    listen = graph.recipe.zenoh_for(process).listen
    if listen is None:
        listen = [PRIVATE] if len(graph.processes()) > 1 and graph.recipe.security is None else []
    return [private_socket(run, process) if e == PRIVATE else e for e in listen]


def _dialled(graph: Graph, process: str, run: str, connect: list[str]) -> dict[str, str]:
    """Which of *connect* is an endpoint another process of the run listens on, and which one."""
    listening = {e: p for p in graph.processes() if p != process for e in _listen_endpoints(graph, p, run)}
    return {e: listening[e] for e in connect if e in listening}


def plan_session(
    graph: Graph, process: str, run: str, *, base: Path | None = None, certs_dir: str | None = None
) -> SessionPlan:
    """The session of *process* in run *run* (*base*: the recipe's folder, for the certificates)."""
    recipe = graph.recipe
    settings = recipe.zenoh_for(process)
    multi = len(graph.processes()) > 1
    sec = recipe.security
    if settings.listen is None and multi and sec is None and not settings.connect:
        settings.connect = [private_socket(run, p) for p in graph.processes() if p != process]
    settings.listen = _listen_endpoints(graph, process, run)
    dialled = _dialled(graph, process, run, settings.connect)
    retry = {"connect/retry": CONNECT_RETRY}
    if sec is None:
        return SessionPlan(settings, retry, dialled=dialled)
    plain = insecure_endpoints([*settings.listen, *settings.connect])
    if plain:
        raise SessionConfigError(
            f"process {process!r}: with security on, every endpoint must be {' or '.join(SECURE_PROTOCOLS)} "
            f"(not {', '.join(plain)})"
        )
    ident = identity(sec, process, base or Path.cwd(), certs_dir)
    acl = acl_for(graph, process, run, sec.observers, sec.controllers)
    extra: dict[str, Any] = {**retry, **tls_entries(ident), "access_control": acl}
    return SessionPlan(settings, extra, secured=True, dialled=dialled)


def security_problems(graph: Graph, *, base: Path | None = None, certs_dir: str | None = None) -> list[str]:
    """What keeps the recipe's ``security:`` block from working, for ``vgr validate`` and before a
    run: endpoints that are not TLS/QUIC, certificate files missing, of another process, not signed
    by the CA, keys readable by others. Empty without a block, or when all is well."""
    sec = graph.recipe.security
    if sec is None:
        return []
    problems: list[str] = []
    for process in graph.processes():
        settings = graph.recipe.zenoh_for(process)
        plain = insecure_endpoints([*(settings.listen or []), *settings.connect])
        if plain:
            problems.append(
                f"process {process!r}: with security on, endpoints must be {' or '.join(SECURE_PROTOCOLS)}: "
                + ", ".join(plain)
            )
        ident = identity(sec, process, base or Path.cwd(), certs_dir)
        problems += [f"process {process!r}: {p}" for p in identity_problems(ident)]
    clash = (set(sec.observers) | set(sec.controllers)) & set(graph.processes())
    if clash:
        problems.append(
            f"observers/controllers {sorted(clash)} have the names of processes: each must be another identity"
        )
    return problems
