"""Runs of two processes of one host (two Runners in this Python process, each with its own zenoh
session, as two ``vgr run --process`` would be) and their links (engine.transport.local_link): an
input linked gets every message once and in order while another consumer of the same port gets
them through zenoh; a port that published before its consumer asked keeps zenoh for it and loses
nothing; ``zenoh: {local_links: false}`` and a consumer killed mid-stream (in test_processes.py and
below, across real processes)."""

from __future__ import annotations

import subprocess
import threading
import time

import pytest
from process_helpers import env, vgr
from recipe_helpers import graph_from
from stage_fixtures import COLLECTED

from engine.run import remote_input
from engine.run.runner import Runner
from engine.run.summary import RunSummary

pytestmark = pytest.mark.timeout(120)

PAIR = """
name: links
plugins: [stage_fixtures]
run_id: {rid}
{zenoh}
stages:
  src:   {{type: t_counter, process: a, params: {{n: {n}, in_setup: {in_setup}}}}}
  sink:  {{type: t_collector, process: b, inputs: {{in: src.out}}}}
  other: {{type: t_collector, process: b, inputs: {{in: src.out}}}}
"""


def run_pair(rid: str, *, n: int = 200, in_setup: int = 0, zenoh: str = "") -> tuple[dict[str, Runner], dict]:
    """Processes a and b of PAIR, each a Runner on a thread: the runners and their summaries."""
    text = PAIR.format(rid=rid, n=n, in_setup=in_setup, zenoh=zenoh)
    runners = {p: Runner(graph_from(text), process=p, ready_timeout_s=30) for p in ("b", "a")}
    out: dict[str, RunSummary] = {}
    threads = [threading.Thread(target=lambda p=p: out.update({p: runners[p].run()}), daemon=True) for p in runners]
    for t in threads:
        t.start()
    for t in threads:
        t.join(90)
    assert not any(t.is_alive() for t in threads), "a process did not end"
    return runners, out


def linked(runner: Runner) -> list[str]:
    """The stages of *runner* whose input ``in`` took a link."""
    return sorted(name for name, rt in runner.runtimes.items() if getattr(rt.inboxes.get("in"), "link", None))


def rows(rid: str, stage: str) -> list[tuple[int, int]]:
    return [(r["seq"], r["args"]["i"]) for r in COLLECTED[rid][stage]]


def test_a_linked_input_gets_every_message_once_while_zenoh_feeds_the_other(monkeypatch):
    real = remote_input.open_link

    def only_sink(run, producer, hello):  # `other` is refused: it stays on zenoh, so the port puts there too
        return real(run, producer, hello) if hello["consumer"] == "sink" else None

    monkeypatch.setattr(remote_input, "open_link", only_sink)
    rid = "links_mixed"
    runners, out = run_pair(rid)
    assert out["a"].ok and out["b"].ok
    assert linked(runners["b"]) == ["sink"]
    want = [(k + 1, k) for k in range(200)]
    assert rows(rid, "sink") == want  # once each (its zenoh copies ignored), in order
    assert rows(rid, "other") == want


def test_a_port_that_published_before_the_link_was_asked_for_keeps_zenoh_and_loses_nothing(monkeypatch):
    real = remote_input.open_link
    runners: dict[str, Runner] = {}

    def after_the_first_messages(run, producer, hello):
        deadline = time.monotonic() + 20  # until src's setup() has published (bounded)
        while time.monotonic() < deadline:
            rt = runners["a"].runtimes.get("src") if "a" in runners else None
            if rt is not None and rt.outputs["out"].seq >= 3:
                break
            time.sleep(0.01)
        return real(run, producer, hello)

    monkeypatch.setattr(remote_input, "open_link", after_the_first_messages)
    monkeypatch.setattr(Runner, "__init__", _remembering(Runner.__init__, runners))
    rid = "links_late"
    _, out = run_pair(rid, n=50, in_setup=3)
    assert out["a"].ok and out["b"].ok
    assert linked(runners["b"]) == []  # refused: the port had sent through zenoh already
    want = [(k + 1, k - 3) for k in range(53)]
    assert rows(rid, "sink") == want and rows(rid, "other") == want


def _remembering(init, runners: dict[str, Runner]):
    def wrapped(self, graph, **kw):
        init(self, graph, **kw)
        runners[kw.get("process", "main")] = self

    return wrapped


def test_local_links_false_sends_everything_through_zenoh():
    rid = "links_off"
    runners, out = run_pair(rid, n=50, zenoh="zenoh: {local_links: false}")
    assert out["a"].ok and out["b"].ok and linked(runners["b"]) == []
    assert rows(rid, "sink") == [(k + 1, k) for k in range(50)]


def test_linked_by_default_on_one_host():
    rid = "links_on"
    runners, out = run_pair(rid, n=50)
    assert out["a"].ok and out["b"].ok and linked(runners["b"]) == ["other", "sink"]
    assert rows(rid, "sink") == rows(rid, "other") == [(k + 1, k) for k in range(50)]


KILL = """
name: killc
record: {{enabled: false}}
plugins: [stage_fixtures]
run_id: killc_{pid}
stages:
  src:  {{type: t_counter, process: producer, params: {{forever: true, rate_hz: 200}}}}
  sink: {{type: t_collector, process: consumer, inputs: {{in: src.out}}}}
"""


@pytest.mark.subprocess
def test_a_consumer_killed_mid_stream_fails_the_producer_naming_it_and_nothing_hangs(tmp_path):
    recipe = tmp_path / "killc.yaml"
    recipe.write_text(KILL.format(pid=threading.get_native_id()))
    opts = {"env": env(), "cwd": tmp_path, "stdout": subprocess.PIPE, "stderr": subprocess.STDOUT, "text": True}
    consumer = subprocess.Popen(vgr("run", str(recipe), "--process", "consumer", "--no-progress"), **opts)
    producer = subprocess.Popen(vgr("run", str(recipe), "--process", "producer", "--no-progress"), **opts)
    log = tmp_path / "runs"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # linked and flowing (the consumer's run.log says when it linked)
        if any("over a unix socket" in p.read_text() for p in log.glob("*consumer/run.log")):
            break
        time.sleep(0.1)
    time.sleep(1.0)
    consumer.kill()  # SIGKILL, mid-stream: the producer's next send finds the link gone
    consumer.wait(10)
    out, _ = producer.communicate(timeout=60)
    assert producer.returncode == 4, out  # failed: its peer is lost
    assert "peer_lost" in out and "'consumer'" in out
    assert "Traceback" not in out
