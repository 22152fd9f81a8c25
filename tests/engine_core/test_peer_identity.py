"""A process of the run is the session zenoh's links show, not whoever declares its ``_peer`` token
(engine.transport.link_identity). The attacks: a program of the same user that reaches the run's
private socket and declares itself the provider process, with every token and marker the real one
would declare, answering its service; and, with ``security:``, a second session holding a valid
certificate of one of the run's processes. Both were taken at their word before (the caller used
the squatter's replies; the second session could call the services).
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import zenoh
from process_helpers import free_port
from recipe_helpers import graph_from
from stage_fixtures import COLLECTED

from engine.graph import build_graph
from engine.messages import Request, codec
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe
from engine.run.runner import Runner
from engine.run.summary import RunError
from engine.security.certs import Identity, write_bundle
from engine.transport.bus import active_key, ready_key, service_key, started_key
from engine.transport.endpoints import private_socket
from engine.transport.peers import members_digest, peer_key

pytestmark = pytest.mark.timeout(120)

# a: the provider (the robot's side); b: the caller, with the source (the vision side)
PAIR = """
name: squat
plugins: [stage_fixtures]
run_id: {rid}
{head}
stages:
  src:  {{type: t_counter, process: b, params: {{n: {n}, rate_hz: 50}}}}
  echo: {{type: t_echo, process: a}}
  call: {{type: t_caller, process: b, inputs: {{in: src.out}}, uses: {{svc: echo.echo}}, params: {{timeout_s: 2}}}}
  sink: {{type: t_collector, process: b, inputs: {{in: call.out}}}}
"""


def in_thread(runner: Runner) -> tuple[threading.Thread, dict[str, object]]:
    """*runner* run in a thread: its summary, or the error that kept it from starting."""
    out: dict[str, object] = {}

    def run() -> None:
        try:
            out["summary"] = runner.run()
        except RunError as exc:
            out["error"] = exc

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th, out


def _session(connect: list[str], extra: dict[str, object] | None = None) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    for path, value in (extra or {}).items():
        conf.insert_json5(path, json.dumps(value))
    return zenoh.open(conf)


class Squatter:
    """Claims process ``a`` of run *rid* on b's private socket: its ``_peer`` token and markers
    (the started digest computed from b's epoch, as the real one would), ``_ready/echo``,
    ``_started/a``, ``_active/a``, and a queryable answering ``echo`` with a forged reply."""

    def __init__(self, rid: str) -> None:
        self.rid = rid
        sock = private_socket(rid, "b").removeprefix("unixsock-stream/")
        deadline = time.monotonic() + 20
        while not Path(sock).exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        self.s = _session([f"unixsock-stream/{sock}"])
        self.tokens: list[object] = []
        self.answered = 0
        self.q = self.s.declare_queryable(service_key(rid, "echo", "echo"), self._forge)

    def _forge(self, query: zenoh.Query) -> None:
        self.answered += 1
        payload, att = codec.encode(Request(command="echo", args={"served_by": "squatter", "x_mm": 33.0}))
        query.reply(query.key_expr, payload, attachment=att)

    def claim(self) -> None:
        b_epoch = ""
        deadline = time.monotonic() + 20
        while not b_epoch and time.monotonic() < deadline:
            for r in self.s.liveliness().get(f"vgr/{self.rid}/_peer/b/*/*", timeout=1.0):
                if r.ok is not None:
                    b_epoch = str(r.ok.key_expr).split("/")[5]
        assert b_epoch, "process b never declared itself"
        me = peer_key(self.rid, "a", str(self.s.zid()), "5e55e55e55e5")
        digest = members_digest({"a": "5e55e55e55e5", "b": b_epoch})
        for key in (me, ready_key(self.rid, "echo"), f"{me}/started/{digest}", started_key(self.rid, "a")):
            self.tokens.append(self.s.liveliness().declare_token(key))
        self.tokens.append(self.s.liveliness().declare_token(active_key(self.rid, "a")))

    def close(self) -> None:
        self.s.close()


def forged(rid: str) -> list[dict]:
    return [r for r in COLLECTED[rid]["sink"] if r["args"].get("served_by") == "squatter"]


def test_a_squatted_peer_token_is_not_taken_for_the_process(tmp_path: Path):
    rid = "squat_alone"
    b = Runner(graph_from(PAIR.format(rid=rid, head="", n=20)), process="b", ready_timeout_s=6)
    tb, rb = in_thread(b)
    squatter = Squatter(rid)
    try:
        squatter.claim()
        tb.join(30)
        if tb.is_alive():  # (taken for process a, b would call it and wait for the end of a run never run)
            b.stop("test: still running")
            tb.join(30)
    finally:
        squatter.close()
    error = str(rb.get("error"))  # the run could not start: nothing answers on a's socket
    assert "summary" not in rb and "process a" in error and str(squatter.s.zid()) in error, rb
    assert "a.sock" in error
    assert forged(rid) == [] and squatter.answered == 0


def test_the_real_process_coming_up_names_the_squatter_and_the_run_stops(tmp_path: Path):
    rid = "squat_then_real"
    text = PAIR.format(rid=rid, head="", n=20)
    b = Runner(graph_from(text), process="b", ready_timeout_s=20)
    tb, rb = in_thread(b)
    squatter = Squatter(rid)
    try:
        squatter.claim()
        time.sleep(0.5)  # b has the claim (held: nothing on a's socket yet)
        ta, _ = in_thread(Runner(graph_from(text), process="a", ready_timeout_s=20))
        tb.join(40)
        ta.join(40)
    finally:
        squatter.close()
    summary = rb["summary"]
    alarms = [e for e in summary.events if e.level == "alarm"]
    assert summary.exit_code == 4 and [e.code for e in alarms] == ["peer_impostor"], summary.events
    assert str(squatter.s.zid()) in alarms[0].message and "'a'" in alarms[0].message
    assert forged(rid) == [] and squatter.answered == 0


def _secured(tmp_path: Path, rid: str, port: int) -> Path:
    head = (
        "security: {certs: certs}\n"
        "processes:\n"
        f'  a: {{listen: ["tls/127.0.0.1:{port}"]}}\n'
        f'  b: {{connect: ["tls/127.0.0.1:{port}"], listen: []}}\n'
    )
    recipe = tmp_path / "squat.yaml"
    recipe.write_text(PAIR.format(rid=rid, head=head, n=400))
    write_bundle(tmp_path / "certs", [Identity("a", ("127.0.0.1",)), Identity("b", ("127.0.0.1",))], ca_name="t")
    return recipe


def _graph(recipe: Path):
    loaded = load_recipe(str(recipe))
    return build_graph(loaded, load_registry(loaded.recipe.plugins))


def test_a_second_session_with_a_process_certificate_stops_the_secured_run(tmp_path: Path):
    rid, port = "shared_cert", free_port()
    recipe = _secured(tmp_path, rid, port)
    ta, ra = in_thread(Runner(_graph(recipe), process="a", ready_timeout_s=20))
    tb, rb = in_thread(Runner(_graph(recipe), process="b", ready_timeout_s=20))
    deadline = time.monotonic() + 30
    while len(COLLECTED[rid]["sink"]) < 5 and time.monotonic() < deadline:
        time.sleep(0.02)
    certs = tmp_path / "certs"
    tls = {
        "root_ca_certificate": str(certs / "ca.pem"),
        "connect_private_key": str(certs / "b.key"),
        "connect_certificate": str(certs / "b.pem"),
        "enable_mtls": True,
    }
    copy = _session([f"tls/127.0.0.1:{port}"], {"transport/link/tls": tls})  # b's key, copied
    try:
        payload, att = codec.encode(Request(command="echo", args={"from": "copy"}))
        replies = list(copy.get(service_key(rid, "echo", "echo"), payload=payload, attachment=att, timeout=3.0))
        ta.join(30)
        tb.join(30)
    finally:
        copy.close()
    a = ra["summary"]
    assert a.exit_code == 4 and "identity_shared" in [e.code for e in a.events if e.level == "alarm"], a.events
    assert str(copy.zid()) in a.stop_reason
    assert not rb["summary"].ok  # b is stopped by a
    assert all(r.ok is None for r in replies), "the copy's request was served"
    assert not [r for r in COLLECTED[rid]["sink"] if r["args"].get("from") == "copy"]
