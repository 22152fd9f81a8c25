"""The dora-rs peer of benchmarks/engine_overhead.py: vgr's two bench stages as a dora dataflow.

dora-rs (pip ``dora-rs`` and ``dora-rs-cli``, 1.1.x; https://dora-rs.ai) is the open dataflow
engine closest to vgr: a YAML graph of nodes, Python nodes, large buffers handed over in shared
memory. This module is both the runner (:func:`run_dataflow`) and the two nodes (``python
dora_peer.py source|sink ...``, started by dora), which do what benchmarks/bench_stages.py's stages
do:

* ``source``: the payload built by ``bench_stages.make_payload`` (``time.monotonic_ns()`` stamped
  into the first 8 bytes just before it is built), paced by ``bench_stages.pace`` (or as fast as
  possible), handed to ``node.send_output`` as ``bytes`` (dora copies them into an Arrow array, in
  shared memory when large, as its Python API does for any ``bytes``);
* start: the sink sends one message on its ``ready`` output once it reads its input, and the
  source waits for it (vgr's source likewise starts once its consumer is ready);
* ``sink``: latency and arrival time taken when the node holds the event with its data (an Arrow
  array, a zero-copy view of dora's buffer: the point where vgr's ``bench_sink`` handler holds its
  decoded Blob), the stamp read from that data; CPU time of both processes over the measured
  messages (``time.process_time()``).

The sink's input keeps dora's default queue (``queue_size`` 10: when it is full, dora drops the
oldest message). A burst therefore loses messages; the sink counts what it received and the result
says ``sent`` / ``received`` (vgr and raw zenoh deliver everything, reliable, congestion control
BLOCK). Warm-up: the first ``warmup`` messages *sent* are not measured; since dora may drop any of
them, the sink keeps every message's stamp and the runner keeps those stamped after the source's
warm-up ended (a burst into a sink that is still starting can lose nearly all of it: measured here,
12 of 2020 64 B messages received in one run, 178 and 419 in two others).

Runs with ``dora run DATAFLOW --stop-after S`` (dora 1.1's local mode: daemon and nodes in one
process tree, no coordinator, nothing left running after it returns), bounded by a subprocess
timeout on top; the dataflow's folder is a temporary one, removed afterwards.

dora's in-process form, operators in one runtime node, is not measured: see the module
``IN_PROCESS_NOTE``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent

IN_PROCESS_NOTE = (
    "not measured: dora's in-process form is operators in one runtime node, and dora 1.1 refuses two "
    "Python operators in one runtime ('dora run' of such a dataflow fails: 'Runtime currently only "
    "supports one Python Operator.'), so vgr's two Python stages cannot be one dora process"
)

DATAFLOW = """
nodes:
  - id: src
    path: {python}
    args: {script} source {size} {count} {interval} {warmup} {src_out}
    outputs: [out]
    inputs:
      ready: sink/ready
  - id: sink
    path: {python}
    args: {script} sink {sink_out}
    inputs:
      in: src/out
    outputs: [ready]
"""


def dora_cli() -> str | None:
    """The ``dora`` command of this Python's environment (or on PATH), None when not installed."""
    beside = Path(sys.executable).with_name("dora")
    return str(beside) if beside.exists() else shutil.which("dora")


def run_dataflow(size: int, count: int, interval_s: float, warmup: int, timeout_s: float = 300) -> dict[str, Any]:
    """Run the two-node dataflow once: the measured messages' ``lat_ns`` and ``arrivals_ns``, the
    CPU seconds of both processes over them (``cpu_s``), ``sent`` and ``received`` (measured ones)."""
    cli = dora_cli()
    if cli is None:
        raise RuntimeError("dora is not installed (pip install 'dora-rs==1.1.*' 'dora-rs-cli==1.1.*')")
    with tempfile.TemporaryDirectory(prefix="vgr-dora-") as tmp:
        src_out, sink_out = Path(tmp) / "src.json", Path(tmp) / "sink.json"
        flow = Path(tmp) / "dataflow.yml"
        flow.write_text(
            DATAFLOW.format(
                python=sys.executable,
                script=Path(__file__).resolve(),
                size=size,
                count=count,
                interval=interval_s,
                warmup=warmup,
                src_out=src_out,
                sink_out=sink_out,
            )
        )
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
        stop_after = f"{int(timeout_s)}s"
        proc = subprocess.run(
            [cli, "run", str(flow), "--stop-after", stop_after, "--log-level", "error"],
            cwd=tmp,
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout_s + 30,
            check=False,
        )
        if proc.returncode or not sink_out.exists() or not src_out.exists():
            raise RuntimeError(f"dora run failed ({proc.returncode}): {proc.stderr[-2000:]}{proc.stdout[-2000:]}")
        sink, src = json.loads(sink_out.read_text()), json.loads(src_out.read_text())
    keep = [i for i, stamp in enumerate(sink["stamps_ns"]) if stamp >= src["t0_ns"]]
    arrivals = [sink["arrivals_ns"][i] for i in keep]
    sink_cpu = sink["cpu_s"][-1] - sink["cpu_s"][keep[0]] if keep else 0.0
    return {
        "lat_ns": [arrivals[k] - sink["stamps_ns"][i] for k, i in enumerate(keep)],
        "arrivals_ns": arrivals,
        "cpu_s": (src["cpu_s"][1] - src["cpu_s"][0]) + sink_cpu,
        "sent": count,
        "received": len(keep),
        "t0_ns": src["t0_ns"],  # when the first measured message was built
    }


# --------------------------------------------------------------------------- the nodes


def source_node(size: int, count: int, interval_s: float, warmup: int, out: str) -> None:
    import dora
    from bench_stages import make_payload, pace

    node = dora.Node()
    event = node.next(timeout=60)  # the sink's "ready": start as vgr's source does, once its consumer listens
    if event is None or event["type"] != "INPUT":
        raise SystemExit(f"source: no ready from the sink ({event})")
    base = bytes(max(size, 8))
    send = node.send_output
    nxt = time.perf_counter()
    cpu0, t0 = 0.0, 0
    for i in range(count + warmup):
        if i == warmup:
            cpu0, t0 = time.process_time(), time.monotonic_ns()
        if interval_s:
            nxt = pace(nxt, interval_s)
        send("out", make_payload(base))
    Path(out).write_text(json.dumps({"cpu_s": [cpu0, time.process_time()], "t0_ns": t0}))


def sink_node(out: str) -> None:
    import dora

    from_bytes = int.from_bytes
    node = dora.Node()
    node.send_output("ready", b"1")
    stamps: list[int] = []
    arrivals: list[int] = []
    cpu: list[float] = []  # process CPU time at each message (the runner keeps the measured span)
    for event in node:
        if event["type"] != "INPUT":
            if event["type"] in ("INPUT_CLOSED", "STOP"):
                break
            continue
        now = time.monotonic_ns()
        data = event["value"].buffers()[1]  # the bytes of the UInt8 array, not copied
        stamps.append(from_bytes(memoryview(data)[:8], "little"))
        arrivals.append(now)
        cpu.append(time.process_time())
    Path(out).write_text(json.dumps({"stamps_ns": stamps, "arrivals_ns": arrivals, "cpu_s": cpu}))


if __name__ == "__main__":
    sys.path[:0] = [str(HERE.parent)]
    from engine.run.process_memory import keep_freed_memory

    keep_freed_memory()  # the allocator settings of a vgr run, as every row of the benchmark has them
    role, args = sys.argv[1], sys.argv[2:]
    if role == "source":
        source_node(int(args[0]), int(args[1]), float(args[2]), int(args[3]), args[4])
    elif role == "sink":
        sink_node(args[0])
    else:
        raise SystemExit(f"unknown role {role!r} (source or sink)")
