"""Where the runs on this machine listen, so ``vgr topics`` and ``vgr play`` find them without flags.

A run's zenoh session listens on loopback by default (``tcp/127.0.0.1:0``: a port the system picks),
and multicast scouting is off, so nothing outside the process can know that port. ``vgr run`` (and
``vgr play``) therefore pin such a port before opening the session (:func:`pin_ports`: a free port
asked of the system, the way a test does) and write ``bus.json`` into their own run folder::

    {"layout": 1, "run_id": "demo", "process": "main", "pid": 4242,
     "endpoints": ["tcp/127.0.0.1:38117"]}

removed again when the run ends. :func:`local_endpoints` reads the files of the live processes
(their pid exists) under a runs folder. A wildcard address (``0.0.0.0``, ``[::]``) is written as the
loopback address a local client connects to. Runs on other hosts are reached with ``--connect``.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
from pathlib import Path

from engine.discovery import LAYOUT_VERSION

FILE_NAME = "bus.json"


def _free_port(host: str) -> int:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def pin_ports(endpoints: list[str]) -> list[str]:
    """*endpoints* with every ``tcp/<host>:0`` given a free port of *host* (others unchanged)."""
    pinned = []
    for ep in endpoints:
        proto, _, address = ep.partition("/")
        host, _, port = address.rpartition(":")
        if proto == "tcp" and port == "0" and host:
            ep = f"tcp/{host}:{_free_port(host.strip('[]'))}"
        pinned.append(ep)
    return pinned


def _reachable(endpoint: str) -> str:
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def write(run_dir: Path, run_id: str, process: str, endpoints: list[str]) -> Path:
    """Write ``bus.json`` into *run_dir* (a folder this process made) and return its path."""
    path = Path(run_dir) / FILE_NAME
    doc = {
        "layout": LAYOUT_VERSION,
        "run_id": run_id,
        "process": process,
        "pid": os.getpid(),
        "endpoints": [_reachable(e) for e in endpoints],
    }
    path.write_text(json.dumps(doc) + "\n")
    return path


def remove(run_dir: Path) -> None:
    with contextlib.suppress(OSError):
        (Path(run_dir) / FILE_NAME).unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: it exists
        return True
    return True


def local_endpoints(runs_dir: str | Path) -> list[str]:
    """Endpoints of the processes whose ``bus.json`` lies in a folder of *runs_dir* and whose pid
    is alive (newest folder first; a file left by a killed run is skipped)."""
    found: list[str] = []
    for path in sorted(Path(runs_dir).glob(f"*/{FILE_NAME}"), reverse=True):
        try:
            doc = json.loads(path.read_text())
            if not _alive(int(doc["pid"])):
                continue
            found.extend(e for e in doc["endpoints"] if isinstance(e, str) and e not in found)
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return found
