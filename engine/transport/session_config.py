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


def plan_session(
    graph: Graph, process: str, run: str, *, base: Path | None = None, certs_dir: str | None = None
) -> SessionPlan:
    """The session of *process* in run *run* (*base*: the recipe's folder, for the certificates)."""
    recipe = graph.recipe
    settings = recipe.zenoh_for(process)
    multi = len(graph.processes()) > 1
    sec = recipe.security
    if settings.listen is None:
        if multi and sec is None:
            settings.listen = [PRIVATE]
            if not settings.connect:
                settings.connect = [private_socket(run, p) for p in graph.processes() if p != process]
        else:
            settings.listen = []
    settings.listen = [private_socket(run, process) if e == PRIVATE else e for e in settings.listen]
    if sec is None:
        return SessionPlan(settings)
    plain = insecure_endpoints([*settings.listen, *settings.connect])
    if plain:
        raise SessionConfigError(
            f"process {process!r}: with security on, every endpoint must be {' or '.join(SECURE_PROTOCOLS)} "
            f"(not {', '.join(plain)})"
        )
    ident = identity(sec, process, base or Path.cwd(), certs_dir)
    acl = acl_for(graph, process, run, sec.observers, sec.controllers)
    extra: dict[str, Any] = {**tls_entries(ident), "access_control": acl}
    return SessionPlan(settings, extra, secured=True)


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
