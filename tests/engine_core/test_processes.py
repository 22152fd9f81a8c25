"""Across OS processes: two processes of one recipe exchange messages exactly as in one process,
over the links of one host (engine.transport.local_link) or, with ``local_links: false``, over zenoh
tcp on 127.0.0.1 (the service calls always); Ctrl-C stops a run cleanly with exit code 130."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import pytest
from process_helpers import env, free_port, run_vgr, start, vgr

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]

RECIPE = """
name: split
plugins: [stage_fixtures]
seed: 5
{zenoh}
processes:
  producer: {{listen: ["tcp/127.0.0.1:{port}"]}}
  consumer: {{connect: ["tcp/127.0.0.1:{port}"], listen: []}}
stages:
  src:   {{type: t_counter, process: {p_src}, params: {{n: 300}}}}
  relay: {{type: t_relay, process: {p_src}, inputs: {{in: src.out}}}}
  echo:  {{type: t_echo, process: {p_src}}}
  call:  {{type: t_caller, process: {p_sink}, inputs: {{in: relay.out}}, uses: {{svc: echo.echo}}}}
  sink:  {{type: t_collector, process: {p_sink}, inputs: {{in: call.out}}, params: {{output: "{out}"}}}}
"""


@pytest.mark.parametrize("links", [True, False], ids=["links", "zenoh"])
def test_two_processes_exchange_messages_like_one(tmp_path, links):
    port = free_port()
    split = tmp_path / "split.yaml"
    zenoh = "" if links else "zenoh: {local_links: false}"
    split.write_text(
        RECIPE.format(zenoh=zenoh, port=port, p_src="producer", p_sink="consumer", out=tmp_path / "split.json")
    )
    single = tmp_path / "single.yaml"
    single.write_text(
        RECIPE.format(zenoh="", port=port, p_src="main", p_sink="main", out=tmp_path / "single.json")
        .replace("processes:", "unused:")
        .replace("unused:\n", "", 1)
    )
    single.write_text(
        "\n".join(
            line
            for line in single.read_text().splitlines()
            if not line.strip().startswith(("unused", "producer:", "consumer:"))
        )
    )

    # consumer first: it must wait for the producer (start-up barrier), not lose early messages
    consumer = start(split, "consumer", tmp_path)
    time.sleep(1.0)
    producer = start(split, "producer", tmp_path)
    out_c, _ = consumer.communicate(timeout=60)
    out_p, _ = producer.communicate(timeout=60)
    assert consumer.returncode == 0, out_c
    assert producer.returncode == 0, out_p
    one = run_vgr("run", str(single), "--no-progress", cwd=tmp_path, timeout=60)
    assert one.returncode == 0, one.stdout + one.stderr
    rows_split = json.loads((tmp_path / "split.json").read_text())
    rows_single = json.loads((tmp_path / "single.json").read_text())
    assert len(rows_split) == 300
    assert rows_split == rows_single  # same content, same order, same sequence numbers
    log = next(tmp_path.glob("runs/*-split-consumer/run.log")).read_text()
    assert ("call: input 'in' takes relay.out over a unix socket of this host" in log) == links, log


def test_missing_process_is_reported_not_hung(tmp_path):
    port = free_port()
    split = tmp_path / "split.yaml"
    split.write_text(RECIPE.format(zenoh="", port=port, p_src="producer", p_sink="consumer", out=tmp_path / "x.json"))
    r = subprocess.run(
        vgr("run", str(split), "--process", "consumer", "--ready-timeout", "2", "--no-progress"),
        env=env(),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert "these stages are not running" in r.stderr and "process producer" in r.stderr


def test_ctrl_c_stops_cleanly_with_exit_code_130(tmp_path):
    recipe = tmp_path / "endless.yaml"
    recipe.write_text("""
name: endless
plugins: [stage_fixtures]
stages:
  src: {type: t_counter, params: {forever: true, rate_hz: 500}}
  mid: {type: t_relay, inputs: {in: src.out}}
  sink: {type: t_collector, inputs: {in: mid.out}}
""")
    p = subprocess.Popen(
        vgr("run", str(recipe), "--no-progress"),
        env=env(),
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60  # wait until the run is under way (its recording exists)...
    while not list((tmp_path / "runs").glob("*/*.mcap")) and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.1)
    time.sleep(1.0)  # ...and messages flow
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 130, out + err
    assert "interrupted (Ctrl-C)" in out
    assert "Traceback" not in err
