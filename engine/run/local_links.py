"""This process's side of the links between the vgr processes of one host
(engine.transport.local_link): the listener its output ports take links on, and its inputs asking
their producers for one."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from engine.run.remote_input import RemoteInput
from engine.transport.local_link import LinkListener
from engine.transport.shm_views import host_key

if TYPE_CHECKING:
    from engine.run.runtime import StageRuntime

log = logging.getLogger("vgr.local_links")


def listen_for_links(run: str, process: str, runtimes: Mapping[str, StageRuntime]) -> LinkListener | None:
    """The listener of this process when one of its ports feeds another process (else None; also
    None, with a warning, when the socket cannot be made: every message then goes through zenoh)."""
    if not any(out.remote_consumers for rt in runtimes.values() for out in rt.outputs.values()):
        return None
    host = host_key()

    def attach(hello: dict[str, Any], sock: Any) -> bool:
        if hello.get("v") != 1 or hello.get("run") != run or hello.get("host") != host:
            return False
        rt = runtimes.get(str(hello.get("stage")))
        out = rt.outputs.get(str(hello.get("port"))) if rt is not None else None
        consumer = (hello.get("process"), hello.get("consumer"), hello.get("input"))
        if out is None or not all(isinstance(x, str) for x in consumer):
            return False
        return out.attach_link(consumer, sock)  # type: ignore[arg-type]

    try:
        return LinkListener(run, process, attach)
    except OSError as exc:
        log.warning("process %s takes no links (its messages go through zenoh): %s", process, exc)
        return None


def link_inputs(runtimes: Mapping[str, StageRuntime]) -> int:
    """Ask the producer of every input fed from another process for a link (each taken is a line of
    the run's log); how many were taken."""
    host = host_key()
    return sum(
        box.try_link(host) for rt in runtimes.values() for box in rt.inboxes.values() if isinstance(box, RemoteInput)
    )
