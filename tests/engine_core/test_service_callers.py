"""A service of a secured run serves only the processes the recipe wires to it
(engine.run.service_port): a request from a session that is no such process, or says nobody, gets
an error and a ``caller_refused`` warning, and the stage never sees it; without ``security:`` it is
served and recorded with its caller. Queries and the host are stand-ins; the port is the real one."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import pytest
from recipe_helpers import graph_from

from engine.messages import Request, codec
from engine.run.service_port import ServicePort
from engine.transport.bus import Inbox, StopMarker

RECIPE = """
name: callers
plugins: [stage_fixtures]
stages:
  src:  {type: t_counter, process: vision, params: {n: 1}}
  echo: {type: t_echo, process: robot}
  call: {type: t_caller, process: vision, inputs: {in: src.out}, uses: {svc: echo.echo}}
  sink: {type: t_collector, process: vision, inputs: {in: call.out}}
"""


@dataclass
class Query:
    zid: str | None
    payload: Any = None
    attachment: Any = None
    replies: list[tuple[str, Any]] = field(default_factory=list)
    key_expr: str = "vgr/callers/echo/srv/echo"
    parameters: Any = None

    def __post_init__(self) -> None:
        data, att = codec.encode(Request(command="echo", args={"from": self.zid}))
        self.payload = SimpleNamespace(to_bytes=lambda: data)
        self.attachment = SimpleNamespace(to_bytes=lambda: att)
        self.source_info = None if self.zid is None else SimpleNamespace(source_id=SimpleNamespace(zid=self.zid))

    def __enter__(self) -> Query:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def reply(self, key: str, payload: Any, attachment: Any = None) -> None:
        self.replies.append(("ok", payload))

    def reply_err(self, text: str) -> None:
        self.replies.append(("err", text))


def serve(secured: bool, queries: list[Query]) -> tuple[list[str], list[str]]:
    """Run echo's port over *queries*; the events it raised and the requests the stage served."""
    graph = graph_from(RECIPE)
    members = {"zv": "vision", "zr": "robot", "zc": "cell"}  # (cell: a process of no stage using echo)
    events: list[str] = []
    served: list[str] = []
    host = SimpleNamespace(
        graph=graph,
        stop_event=threading.Event(),
        secured=secured,
        observers=[],
        process_of=lambda zid: members.get(zid),
    )
    rt = SimpleNamespace(
        name="echo",
        node=graph.nodes["echo"],
        host=host,
        event=lambda level, code, msg, **kw: events.append(code),
    )
    inbox = Inbox("vgr/callers/echo/srv/echo")

    def handle(svc: str, reply_type: type, request: Request) -> tuple[tuple[bytes, bytes], str]:
        served.append(str(request.args["from"]))
        return codec.encode(Request(command="echo")), ""

    port = ServicePort(rt, "echo", inbox, handle)  # type: ignore[arg-type]
    for q in queries:
        inbox(q)
    inbox(StopMarker())
    port.pump()
    return events, served


@pytest.mark.parametrize("secured", [True, False])
def test_only_the_wired_process_is_served_in_a_secured_run(secured: bool):
    queries = [Query("zv"), Query("zr"), Query("zc"), Query("z-stranger"), Query(None)]
    events, served = serve(secured, queries)
    if secured:  # vision uses echo; robot is echo's own process; the others are refused
        assert served == ["zv", "zr"]
        assert events == ["caller_refused"] * 3
        assert [q.replies[0][0] for q in queries] == ["ok", "ok", "err", "err", "err"]
        assert "not a caller of this service" in queries[2].replies[0][1]
    else:  # the run's own user, or an endpoint the recipe left open: served (and recorded)
        assert served == ["zv", "zr", "zc", "z-stranger", "None"] and events == []
