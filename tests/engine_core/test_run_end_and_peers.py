"""The run's end is found from the changes, not by walking the graph: a chain of pass-through stages
walks the edge list a fixed number of times whatever its length; and a peer process killed mid-run
(SIGKILL: its tokens vanish without its ``done`` marker) is an alarm naming it, exit code 1."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest
from process_helpers import env, free_port, vgr
from recipe_helpers import graph_from

from engine.run.runner import Runner

ROOT = Path(__file__).resolve().parents[2]


class CountingList(list):
    walks = 0

    def __iter__(self):  # type: ignore[no-untyped-def]
        CountingList.walks += 1
        return super().__iter__()


def chain(n: int, rid: str) -> str:
    lines = [
        f"name: chain\nplugins: [stage_fixtures]\nrun_id: {rid}\nstages:",
        "  s0: {type: t_counter, params: {n: 200}}",
    ]
    lines += [f"  s{i}: {{type: t_relay, inputs: {{in: s{i - 1}.out}}}}" for i in range(1, n + 1)]
    lines.append(f"  sink: {{type: t_collector, inputs: {{in: s{n}.out}}}}")
    return "\n".join(lines) + "\n"


@pytest.mark.timeout(120)
def test_a_chain_of_stages_walks_the_graph_a_fixed_number_of_times():
    n = 80
    graph = graph_from(chain(n, "chain_t6"))
    graph.edges = CountingList(graph.edges)
    CountingList.walks = 0
    runner = Runner(graph)
    summary = runner.run()
    assert summary.ok
    assert CountingList.walks <= 2  # (main walked every edge per stage and per 50 ms tick: hundreds)
    assert runner.done_checks <= 3 * (n + 2)  # one evaluation per change of a stage


@pytest.mark.timeout(180)
def test_a_chain_of_200_idle_stages_in_one_process_delivers_everything_in_order():
    """Each idle stage's handler runs on its producer's thread; nested 200 deep that overflowed the
    interpreter's stack (RecursionError). Past engine.run.runtime.MAX_INLINE_DEPTH a message goes to the
    consumer's own thread instead."""
    from stage_fixtures import COLLECTED

    summary = Runner(graph_from(chain(200, "chain_200"))).run()
    assert summary.ok, summary.stop_reason
    rows = COLLECTED["chain_200"]["sink"]
    assert [r["args"]["i"] for r in rows] == list(range(200))


@pytest.mark.timeout(180)
def test_a_chain_of_1000_stages_ends_in_order():
    """The end settles each stage's consumers in turn; done by recursion, a chain of 1000 stages
    overflowed the interpreter's stack as the end came down it (RecursionError in the runner)."""
    from stage_fixtures import COLLECTED

    summary = Runner(graph_from(chain(1000, "chain_1000").replace("n: 200", "n: 5"))).run()
    assert summary.ok, summary.stop_reason
    assert [r["args"]["i"] for r in COLLECTED["chain_1000"]["sink"]] == list(range(5))


KILL = """
name: kill
record: {{enabled: false}}
plugins: [stage_fixtures]
run_id: kill_t5
processes:
  producer: {{listen: ["tcp/127.0.0.1:{port}"]}}
  consumer: {{connect: ["tcp/127.0.0.1:{port}"], listen: []}}
stages:
  src:  {{type: t_counter, process: producer, params: {{forever: true, rate_hz: 50}}}}
  sink: {{type: t_collector, process: consumer, inputs: {{in: src.out}}}}
"""


@pytest.mark.subprocess
@pytest.mark.timeout(120)
def test_a_peer_killed_mid_run_is_an_alarm_naming_it_and_the_run_fails(tmp_path):
    recipe = tmp_path / "kill.yaml"
    port = free_port()
    recipe.write_text(KILL.format(port=port))

    opts = {"env": env(), "cwd": tmp_path, "stdout": subprocess.PIPE, "stderr": subprocess.STDOUT, "text": True}
    producer, consumer = (
        subprocess.Popen(vgr("run", str(recipe), "--process", p, "--no-progress"), **opts)
        for p in ("producer", "consumer")
    )
    # both processes set up and answering (engine.transport.discovery), messages flowing: a fixed sleep was too
    # short on a loaded machine, where starting the two processes took more than 6 s
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        listed = subprocess.run(
            vgr("topics", "list", "--json", "--run-id", "kill_t5", "--connect", f"tcp/127.0.0.1:{port}"),
            env=env(),
            capture_output=True,
            text=True,
            timeout=60,
        )
        if listed.returncode == 0 and "/src/out" in listed.stdout:
            break
    time.sleep(1.0)
    producer.kill()  # SIGKILL: no done marker
    producer.wait(10)
    out, _ = consumer.communicate(timeout=60)
    assert consumer.returncode == 4, out  # failed
    assert "peer_lost" in out and "'producer'" in out
