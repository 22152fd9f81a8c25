"""Zenoh endpoint strings (``tcp/127.0.0.1:7447``, ``tls/[::1]:7447``, ``unixsock-stream/path``):
checked when a recipe or the command line is read, so a typo is an error of ``vgr validate``
naming the endpoint, not a failure deep in zenoh when the run opens its session.

The syntax is zenoh's: ``<protocol>/<address>[?<metadata>][#<config>]`` (zenoh's documentation,
"Zenoh endpoints"). Host names are accepted as they are (resolving them is the network's job);
IP addresses and ports are checked for range.
"""

from __future__ import annotations

import glob
import ipaddress
import os
import re
import stat
import tempfile
from pathlib import Path

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


# --------------------------------------------------------------------------- private unix sockets

#: ``listen: [private]`` in a recipe or ``--listen private``: a unix socket in private_socket_dir()
PRIVATE = "private"


def private_socket_dir() -> Path:
    """A folder only this user can open, for the unix sockets of runs on this host:
    ``$XDG_RUNTIME_DIR/vgr`` when set (systemd makes that folder per user, mode 0700), else
    ``<tmp>/vgr-<uid>``. Created 0700; refused (PermissionError) when it exists but belongs to
    another user or others may open it, because a folder planted there by someone else would let
    them take the sockets' names."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    folder = Path(runtime) / "vgr" if runtime else Path(tempfile.gettempdir()) / f"vgr-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    st = folder.lstat()
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise PermissionError(
            f"{folder} must be a folder of user {os.getuid()} with mode 0700 (it is uid {st.st_uid}, "
            f"mode {stat.S_IMODE(st.st_mode):o}): remove it, or set XDG_RUNTIME_DIR to a private folder"
        )
    return folder


def private_socket(run: str, process: str) -> str:
    """The endpoint of *process* of run *run* in private_socket_dir() (the run's folder is made 0700)."""
    run_dir = private_socket_dir() / run
    run_dir.mkdir(mode=0o700, exist_ok=True)
    return f"unixsock-stream/{run_dir / f'{process}.sock'}"


def run_sockets(run: str | None = None) -> list[str]:
    """Endpoints of the sockets run *run*'s processes listen on (those that exist now; None: every
    run of this user on this host). A socket a killed run left behind connects to nothing."""
    runs = "*" if run is None else glob.escape(run)
    return sorted(f"unixsock-stream/{p}" for p in private_socket_dir().glob(f"{runs}/*.sock"))
