"""Which zenoh session is which process of a run, decided from this session's own links, never from
what a session says of itself.

A ``_peer/<process>/<zid>/<epoch>`` liveliness token (engine.transport.peers) is a claim: any session
that reaches the run may declare one. What zenoh itself knows of each link of this session
(``Session.info.links()``, zenoh 1.x) is not a claim: the remote session's ZenohId (``Link.zid``),
the endpoint this session dialled to make it (``Link.dst``) and, over mutual TLS, the Common Name
of the remote's certificate (``Link.auth_identifier``). :class:`LinkIdentity` checks each claim
against them:

* **with ``security:``** — a claim of *process* by *zid* is refused when a link from a session with
  *process*'s certificate reaches another session (two sessions hold that certificate: a copied
  key), or when *zid*'s link shows another certificate. When no link of this session shows that
  certificate (the process is reached through another one), the claim is taken: zenoh's access
  list lets only a session with that certificate declare it (engine.transport.acl).
  :meth:`LinkIdentity.shared_certificates` names the certificates more than one session holds.
* **without** — where this session dials the endpoint *process* listens on (the private unix
  sockets of a multi-process run, engine.transport.endpoints, or a ``listen`` endpoint the recipe
  gives the process), the session at the end of that link is *process*: a claim by any other
  session is refused. Over a unix socket (the path is exact) a claim waits until that link is up;
  over an IP endpoint it is checked when a link shows one of the addresses the endpoint resolves
  to and taken otherwise (zenoh may report another spelling of the address, and a run must not wait
  for a link it cannot recognise; such an endpoint is unauthenticated anyway: docs/security.md). A
  process this session dials no endpoint of is taken on its claim.

Over the private sockets the remaining gap is a program of the same user that takes a process's
socket before the process starts: the process then refuses to start (its socket is held, exit 2),
so the run does not go ahead unnoticed, but this check cannot tell the two apart.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class LinkFacts:
    """What zenoh says of one link of this session."""

    zid: str  # the remote session
    dst: str  # the endpoint at the remote end (the one dialled, for a link this session opened)
    certificate: str | None  # the remote's certificate Common Name (mutual TLS), else None


@dataclass(frozen=True)
class Verdict:
    """Whether a claim is taken: accepted, refused (with why) or not known yet (neither)."""

    accepted: bool
    refusal: str = ""

    @property
    def pending(self) -> bool:
        return not self.accepted and not self.refusal


ACCEPT = Verdict(True)
PENDING = Verdict(False)


def link_facts(link: Any) -> LinkFacts:
    """What is checked of one ``zenoh.Link``."""
    return LinkFacts(str(link.zid), str(link.dst), link.auth_identifier or None)


def session_links(session: Any) -> list[LinkFacts]:
    """The links of zenoh *session* now."""
    return [link_facts(link) for link in session.info.links()]


EXACT_PROTOCOLS = ("unixsock-stream",)  # endpoints zenoh reports exactly as they were written


def endpoint_addresses(endpoint: str) -> set[str]:
    """The forms *endpoint* can take in ``Link.dst``: itself, and for an IP endpoint every
    ``<proto>/<address>:<port>`` its host resolves to (zenoh reports the address it reached; an
    unspecified address, 0.0.0.0 or ::, is reached as loopback). Metadata and configuration after
    ``?`` or ``#`` are not part of the address."""
    plain = endpoint.split("#", 1)[0].split("?", 1)[0]
    forms = {plain}
    proto, _, rest = plain.partition("/")
    if proto in EXACT_PROTOCOLS or ":" not in rest:
        return forms
    host, _, port = rest.rpartition(":")
    host = host.strip("[]")
    try:
        infos = socket.getaddrinfo(host, int(port), proto=socket.IPPROTO_TCP)
    except (OSError, ValueError):
        return forms
    for info in infos:
        addr = ipaddress.ip_address(str(info[4][0]).split("%", 1)[0])
        if addr.is_unspecified:
            addr = ipaddress.ip_address("127.0.0.1" if addr.version == 4 else "::1")
        forms.add(f"{proto}/{addr}:{port}" if addr.version == 4 else f"{proto}/[{addr}]:{port}")
    return forms


class LinkIdentity:
    """Checks claims of run processes against the links of one session (see the module docstring).

    *links*: the session's links now (:func:`session_links`); *own*: this process; *secured*: the
    run has ``security:``; *dialled*: endpoint this session connects to -> the process listening
    there (only the endpoints whose process the recipe says)."""

    def __init__(
        self,
        links: Callable[[], list[LinkFacts]],
        own: str,
        *,
        secured: bool,
        dialled: dict[str, str] | None = None,
    ) -> None:
        self._links = links
        self.own = own
        self.secured = secured
        self._dialled: dict[str, str] = {}
        for endpoint, process in (dialled or {}).items():
            for form in endpoint_addresses(endpoint):
                self._dialled[form] = process

    def verdict(self, process: str, zid: str) -> Verdict:
        """Is session *zid* the run's *process*?"""
        links = self._links()
        return self._by_certificate(process, zid, links) if self.secured else self._by_endpoint(process, zid, links)

    def _by_certificate(self, process: str, zid: str, links: list[LinkFacts]) -> Verdict:
        holders = {link.zid for link in links if link.certificate == process}
        if holders - {zid}:
            return Verdict(
                False,
                f"zenoh session {', '.join(sorted(holders - {zid}))} also holds the certificate of "
                f"process {process!r}: two sessions with one identity (a copied key)",
            )
        shown = {link.certificate for link in links if link.zid == zid}
        if shown - {process}:
            return Verdict(False, f"zenoh session {zid} shows the certificate of {sorted(shown - {process})}")
        return ACCEPT

    def _by_endpoint(self, process: str, zid: str, links: list[LinkFacts]) -> Verdict:
        own_ends = [form for form, p in self._dialled.items() if p == process]
        if not own_ends:
            return ACCEPT  # this session dials no endpoint of that process: nothing to check against
        at_end = {link.zid for link in links if link.dst in own_ends}
        if not at_end:  # (wait only where the link's address is sure to be recognised)
            exact = any(e.partition("/")[0] in EXACT_PROTOCOLS for e in own_ends)
            return PENDING if exact else ACCEPT
        if zid in at_end:
            return ACCEPT
        return Verdict(
            False,
            f"zenoh session {zid} claims to be process {process!r}, but the session on {process!r}'s "
            f"endpoint {own_ends[0]} is {', '.join(sorted(at_end))}",
        )

    def shared_certificates(
        self, processes: Iterable[str], own_zid: str, also: Iterable[LinkFacts] = ()
    ) -> dict[str, set[str]]:
        """With ``security:``: the run's processes whose certificate more than one session holds, with
        the sessions (this process's own certificate shown by any other session counts: two sessions
        with one identity); *also*: links to count besides the session's. Empty without ``security:``."""
        if not self.secured:
            return {}
        holders: dict[str, set[str]] = {}
        for link in [*self._links(), *also]:
            if link.certificate is not None:
                holders.setdefault(link.certificate, set()).add(link.zid)
        holders.setdefault(self.own, set()).add(own_zid)
        wanted = set(processes)
        return {p: zids for p, zids in holders.items() if p in wanted and len(zids) > 1}
