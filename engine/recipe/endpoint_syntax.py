"""Zenoh endpoint strings (``tcp/127.0.0.1:7447``, ``tls/[::1]:7447``, ``unixsock-stream/path``):
checked when a recipe or the command line is read, so a typo is an error of ``vgr validate``
naming the endpoint, not a failure deep in zenoh when the run opens its session.

The syntax is zenoh's: ``<protocol>/<address>[?<metadata>][#<config>]`` (zenoh's documentation,
"Zenoh endpoints"). Host names are accepted as they are (resolving them is the network's job);
IP addresses and ports are checked for range. ``private`` stands for a private unix socket
(engine.transport.endpoints). A leaf module: the recipe model checks its endpoints with it.
"""

from __future__ import annotations

import ipaddress
import re

#: ``listen: [private]`` in a recipe or ``--listen private``: a unix socket in private_socket_dir()
PRIVATE = "private"

#: protocols whose address is ``host:port``
HOST_PORT = ("tcp", "udp", "tls", "quic", "ws")
#: protocols whose address is a path or a name
PATHLIKE = ("unixsock-stream", "unixpipe", "vsock")
_HOSTNAME = re.compile(
    r"^(?=.{1,253}$)([A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$"
)


def endpoint_problem(endpoint: str) -> str | None:
    """Why *endpoint* is not a zenoh endpoint vgr can use, or None when it is."""
    if endpoint == PRIVATE:
        return None
    proto, sep, rest = endpoint.partition("/")
    if not sep or not rest:
        return f"{endpoint!r}: expected <protocol>/<address>, e.g. tcp/127.0.0.1:7447"
    address = re.split(r"[?#]", rest, maxsplit=1)[0]
    if proto in PATHLIKE:
        return None if address else f"{endpoint!r}: {proto} needs a path"
    if proto not in HOST_PORT:
        known = ", ".join((*HOST_PORT, *PATHLIKE))
        return f"{endpoint!r}: unknown protocol {proto!r} (one of {known})"
    host, colon, port = address.rpartition(":")
    if not colon or not host:
        return f"{endpoint!r}: expected host:port after {proto}/"
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        return f"{endpoint!r}: port {port!r} is not a number in 0..65535"
    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            return f"{endpoint!r}: {host} is not an IPv6 address"
        return None
    if re.fullmatch(r"[\d.]+", host):  # looks like IPv4: must be one
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f"{endpoint!r}: {host} is not an IPv4 address"
        return None
    return None if _HOSTNAME.match(host) else f"{endpoint!r}: {host!r} is not a host name"


def check_endpoints(endpoints: list[str]) -> list[str]:
    """*endpoints* unchanged; ValueError naming every bad one (a pydantic validator)."""
    problems = [p for p in (endpoint_problem(e) for e in endpoints) if p]
    if problems:
        raise ValueError("; ".join(problems))
    return endpoints
