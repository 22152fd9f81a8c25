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
* ``sink``: latency and arrival time taken when the node holds the event with its data (an Arrow
  array, a zero-copy view of dora's buffer: the point where vgr's ``bench_sink`` handler holds its
  decoded Blob), the stamp read from that data; CPU time of both processes over the measured
  messages (``time.process_time()``).

The sink's input keeps dora's default queue (``queue_size`` 10: when it is full, dora drops the
oldest message). A burst therefore loses messages; the sink counts what it received and the result
says ``sent`` / ``received`` (vgr and raw zenoh deliver everything, reliable, congestion control
BLOCK). Warm-up: the first ``warmup`` messages *received* are not measured.

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
    "not measured: dora 1.1's in-process form is operators in one runtime node, but a Python "
    "operator only runs inside an event callback (on_event) fed by the daemon, so a source cannot "
    "publish a paced stream or a burst from its own loop as bench_source does; and operators of one "
    "runtime still exchange their outputs through the dora daemon"
)

DATAFLOW = """
nodes:
  - id: src
    path: {python}
    args: {script} source {size} {count} {interval} {warmup} {src_out}
    outputs: [out]
  - id: sink
    path: {python}
    args: {script} sink {warmup} {sink_out}
    inputs:
      in: src/out
"""


def dora_cli() -> str | None:
    """The ``dora`` command of this Python's environment (or on PATH), None when not installed."""
    beside = Path(sys.executable).with_name("dora")
    return str(beside) if beside.exists() else shutil.which("dora")


def run_dataflow(size: int, count: int, interval_s: float, warmup: int, timeout_s: float = 300) -> dict[str, Any]:
    """Run the two-node dataflow once: the sink's and the source's figures (``lat_ns``,
    ``arrivals_ns``, ``cpu_s`` of each, ``sent``, ``received``)."""
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
    return sink | {"src_cpu_s": src["cpu_s"], "sent": src["sent"]}


# --------------------------------------------------------------------------- the nodes


def source_node(size: int, count: int, interval_s: float, warmup: int, out: str) -> None:
    import dora
    from bench_stages import make_payload, pace

    node = dora.Node()
    base = bytes(max(size, 8))
    send = node.send_output
    nxt = time.perf_counter()
    cpu0 = 0.0
    for i in range(count + warmup):
        if i == warmup:
            cpu0 = time.process_time()
        if interval_s:
            nxt = pace(nxt, interval_s)
        send("out", make_payload(base))
    Path(out).write_text(json.dumps({"cpu_s": [cpu0, time.process_time()], "sent": count + warmup}))


def sink_node(warmup: int, out: str) -> None:
    import dora
    import numpy as np

    node = dora.Node()
    lat: list[int] = []
    arrivals: list[int] = []
    cpu = [0.0, 0.0]
    n = 0
    for event in node:
        if event["type"] != "INPUT":
            if event["type"] in ("INPUT_CLOSED", "STOP"):
                break
            continue
        now = time.monotonic_ns()
        n += 1
        if n <= warmup:
            continue
        data = event["value"].buffers()[1]  # the bytes of the UInt8 array, not copied
        lat.append(now - int(np.frombuffer(data, dtype="<i8", count=1)[0]))
        arrivals.append(now)
        if len(lat) == 1:
            cpu[0] = time.process_time()
        cpu[1] = time.process_time()
    Path(out).write_text(json.dumps({"lat_ns": lat, "arrivals_ns": arrivals, "cpu_s": cpu, "received": n}))


if __name__ == "__main__":
    role, args = sys.argv[1], sys.argv[2:]
    if role == "source":
        source_node(int(args[0]), int(args[1]), float(args[2]), int(args[3]), args[4])
    elif role == "sink":
        sink_node(int(args[0]), args[1])
    else:
        raise SystemExit(f"unknown role {role!r} (source or sink)")
