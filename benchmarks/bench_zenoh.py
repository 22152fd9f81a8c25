"""Raw zenoh sessions for the benchmarks' peer rows: a free loopback port and a peer session with
multicast scouting off (the embedded set-up a vgr process has), listening or connecting where told."""

from __future__ import annotations

import json
import socket
from typing import Any

import zenoh


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def peer_session(
    listen: list[str] | None = None, connect: list[str] | None = None, entries: dict[str, Any] | None = None
) -> zenoh.Session:
    """A zenoh peer session on *listen* / *connect* endpoints, with further config *entries*
    (path -> value, e.g. ``{"transport/shared_memory/enabled": True}``)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(listen or []))
    conf.insert_json5("connect/endpoints", json.dumps(connect or []))
    for path, value in (entries or {}).items():
        conf.insert_json5(path, json.dumps(value))
    return zenoh.open(conf)
