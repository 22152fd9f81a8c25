"""Nobody but the run's own processes is taken at its word (engine.transport.peers): an impostor answering a
stage's service is refused with an alarm and nothing is taken from the request; STOP envelopes and
``_control`` messages from a session outside the run are refused with a warning and the run goes on;
each served request is recorded with its caller; a process started again mid-run is refused unless the
recipe says ``rejoin: true``. The intruder is a plain zenoh session on 127.0.0.1."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh
from process_helpers import free_port
from recipe_helpers import graph_from
from stage_fixtures import COLLECTED

from engine.messages import Request, codec
from engine.recording.reader import load
from engine.recording.recorder import Recorder
from engine.run.runner import Runner, RunSummary
from engine.transport.bus import STOP_ENVELOPE, control_key, service_key

pytestmark = pytest.mark.timeout(90)
PLUGINS = ["builtin", "stage_fixtures"]


@contextmanager
def intruder(listen: list[str] = (), connect: list[str] = ()) -> Iterator[zenoh.Session]:  # type: ignore[assignment]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    session = zenoh.open(conf)
    try:
        yield session
    finally:
        session.close()


def in_thread(runner: Runner) -> tuple[threading.Thread, dict[str, RunSummary]]:
    out: dict[str, RunSummary] = {}
    th = threading.Thread(target=lambda: out.update(summary=runner.run()), daemon=True)
    th.start()
    return th, out


def wait_rows(rid: str, stage: str, n: int, timeout_s: float = 20.0) -> list[dict]:
    deadline = time.monotonic() + timeout_s
    while len(COLLECTED[rid][stage]) < n and time.monotonic() < deadline:
        time.sleep(0.01)
    return COLLECTED[rid][stage]


ONE = """
name: forged
plugins: [stage_fixtures]
run_id: {rid}
zenoh: {{connect: ["tcp/127.0.0.1:{port}"], listen: []}}
stages:
  src:  {{type: t_counter, params: {{n: 5, rate_hz: 5}}}}
  echo: {{type: t_echo}}
  call: {{type: t_caller, inputs: {{in: src.out}}, uses: {{svc: echo.echo}}}}
  sink: {{type: t_collector, inputs: {{in: call.out}}}}
"""


def test_a_forged_reply_is_refused_with_an_alarm_and_the_caller_gets_no_result():
    rid, port = "forged_t1", free_port()
    with intruder(listen=[f"tcp/127.0.0.1:{port}"]) as s:
        forged = Request(command="echo", args={"served_by": "impostor", "moved_mm": 100})

        def answer(query: zenoh.Query) -> None:  # a well-formed reply of the right type, from the wrong session
            payload, att = codec.encode(forged)
            query.reply(query.key_expr, payload, attachment=att)

        q = s.declare_queryable(service_key(rid, "echo", "echo"), answer)
        summary = Runner(graph_from(ONE.format(rid=rid, port=port)), observers=[]).run()
        q.undeclare()
    rows = COLLECTED[rid]["sink"]
    assert len(rows) == 5
    assert not any(r["args"].get("served_by") == "impostor" for r in rows)  # nothing taken from the impostor
    # once the impostor's queryable is known, a request has two replies and none is taken (not even the
    # owner's); before that (the first one, maybe) only the owner answered
    alarms = [e for e in summary.events if e.code == "forged_reply"]
    refused = [r for r in rows if r["command"] == "error"]
    assert len(alarms) == len(refused) >= 4 and str(s.zid()) in alarms[-1].message
    assert all(r["args"]["served_by"] == "echo" for r in rows if r["command"] != "error")
    assert summary.outcome == "refused" and summary.exit_code == 1


TWO = """
name: outsider
plugins: [stage_fixtures]
run_id: {rid}
rejoin: {rejoin}
processes:
  a: {{listen: ["tcp/127.0.0.1:{port}"]}}
  b: {{connect: ["tcp/127.0.0.1:{port}"], listen: []}}
stages:
  src:  {{type: t_counter, process: a, params: {{n: {n}, rate_hz: 50}}}}
  echo: {{type: t_echo, process: a}}
  call: {{type: t_caller, process: b, inputs: {{in: src.out}}, uses: {{svc: echo.echo}}}}
  sink: {{type: t_collector, process: b, inputs: {{in: call.out}}}}
"""


def two(rid: str, port: int, n: int = 40, rejoin: bool = False) -> tuple[str, ...]:
    return (TWO.format(rid=rid, port=port, n=n, rejoin=str(rejoin).lower()),)


def test_stop_and_control_from_outside_the_run_are_refused_and_the_run_finishes_ok(tmp_path: Path):
    rid, port = "outsider_t2", free_port()
    text = two(rid, port, n=150)[0]
    graph = graph_from(text)
    rec = Recorder(tmp_path / "a.mcap", graph.recipe.record, graph.loaded, PLUGINS)
    ta, ra = in_thread(Runner(graph, process="a", observers=[rec], ready_timeout_s=20))
    tb, rb = in_thread(Runner(graph_from(text), process="b", ready_timeout_s=20))
    assert len(wait_rows(rid, "sink", 5)) >= 5
    with intruder(connect=[f"tcp/127.0.0.1:{port}"]) as s:
        time.sleep(0.5)  # connected
        s.put(control_key(rid), json.dumps({"stop": "intruder says stop", "process": "a"}).encode())
        list(s.get(service_key(rid, "echo", "echo"), attachment=STOP_ENVELOPE, timeout=2.0))
        payload, att = codec.encode(Request(command="echo", args={"from": "outside"}))
        list(s.get(service_key(rid, "echo", "echo"), payload=payload, attachment=att, timeout=2.0))
        ta.join(30)
        tb.join(30)
    a, b = ra["summary"], rb["summary"]
    assert a.ok and b.ok, (a.stop_reason, b.stop_reason)
    assert len(COLLECTED[rid]["sink"]) == 150 and all(r["command"] == "echo" for r in COLLECTED[rid]["sink"])
    codes_a = [e.code for e in a.events]  # (b listens nowhere: the intruder reaches a only)
    assert "control_refused" in codes_a and "stop_refused" in codes_a
    # every request a served is recorded with its caller: process b's 150, and the outsider's one
    served = [r for r in load(tmp_path / "a.mcap").records if r[0] == "served"]
    callers = [r[3] for r in served]
    assert callers.count("b") == 150
    outside = [r for r in served if r[3] == ""]
    assert len(outside) == 1 and outside[0][4] == ""  # a plain session's query does not say who it is
    assert {r[4] for r in served if r[3] == "b"} and "" not in {r[4] for r in served if r[3] == "b"}


@pytest.mark.parametrize("rejoin", [False, True])
def test_a_process_started_again_mid_run_is_refused_unless_the_recipe_allows_rejoining(rejoin: bool):
    rid, port = f"restart_t4_{rejoin}", free_port()
    text = two(rid, port, n=100, rejoin=rejoin)[0]
    ta, ra = in_thread(Runner(graph_from(text), process="a", ready_timeout_s=20))
    tb, rb = in_thread(Runner(graph_from(text), process="b", ready_timeout_s=20))
    assert len(wait_rows(rid, "sink", 5)) >= 5
    again = Runner(graph_from(text), process="b", ready_timeout_s=5)  # b started a second time
    tc, rc = in_thread(again)
    if not rejoin:
        tc.join(30)
        c = rc["summary"]
        assert not c.ok and c.exit_code == 4
        assert [e.code for e in c.events if e.level == "alarm"] == ["rejoin_refused"]
    for t in (ta, tb, tc):
        t.join(40)
    a, b, c = ra["summary"], rb["summary"], rc["summary"]
    assert a.ok and b.ok, (a.stop_reason, b.stop_reason)  # the run itself goes on
    if not rejoin:
        assert "rejoin_refused" in [e.code for e in a.events]
    else:  # (a still flags a second b while the first one lives: rejoining takes the place of a vanished one)
        assert "rejoined" in [e.code for e in c.events] and "rejoin_refused" not in [e.code for e in c.events]
