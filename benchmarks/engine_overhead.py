"""Engine overhead: stage-to-stage latency and throughput through vgr vs raw zenoh, same run.

Payloads of 64 B, 4 KiB and 1.2 MB, in two topologies:

* in-process — raw: one zenoh session, ``put`` -> subscriber callback (which reads the payload
  bytes); vgr: ``bench_source`` -> ``bench_sink`` in one process (intra-process hand-over);
* cross-process over tcp/127.0.0.1 — raw: publisher here, subscriber callback in a child process;
  vgr: the same two stages in two ``vgr run --process`` processes; ``vgr_secured``: the same with
  the recipe's ``security:`` block (TLS over 127.0.0.1, mutual TLS, zenoh's access-control list
  built from the graph; docs/security.md), so ``secured_over_plain_*`` is what security costs.

Latency is one-way, from just before the payload is built (``time.monotonic_ns()``, the same clock in
every process) to the moment the receiving code holds the data: the entry of the vgr stage handler
(the message received and decoded) and, for raw zenoh, the subscriber callback once it has read the
payload bytes (``payload.to_bytes()``, the copy out of zenoh's buffers that any use of the data
needs; for 1.2 MB it takes 0.1-0.2 ms, which the vgr handler's entry includes). Messages are paced
so that nothing queues; median / p90 / p99 over ``count`` messages after a warm-up. The raw rows
also give ``p50_entry_us``, measured at the callback's entry before the bytes are read. Throughput is messages per
second at the receiver when the sender publishes as fast as it can (reliable, congestion control
BLOCK, nothing dropped). The vgr processes run without recording (``--no-record``): recording costs
are benchmarks/record_replay.py's subject.

raw and vgr alternate run by run (raw, vgr, raw, vgr, ... for each payload), so load from other
programs drifting over time hits both alike; medians over ``--repeat`` runs (default 5), and, per
row, the ratio of each pair of alternated runs (``*_runs``: their spread is this machine's
run-to-run noise; on a shared 2-vCPU VM raw zenoh's small-message rate moves by up to +-30 %).
Each run also notes the CPU time its processes spent (``time.process_time()``, every thread,
zenoh's included) from the first to the last measured message: ``cpu_us_per_msg``, and
``throughput_ratio_cpu`` = raw CPU per message / vgr CPU per message, the throughput ratio a
CPU-bound run would show. On a machine shared with other work that figure is the steadier one; the
wall-clock ratios are what the targets name.

Across processes, ``dora`` is the same pair of stages as a dora-rs 1.1 dataflow of two Python nodes
(benchmarks/dora_peer.py: same payload, same stamp, same receive point, run with ``dora run``), the
peer a user would pick instead of vgr; it runs in the same alternation (raw, vgr, vgr_secured, dora
for each payload) and ``ratios_vgr_over_dora`` gives vgr / dora per row. dora's input queue keeps
its default (10, oldest dropped when full), so a burst loses messages: every row says what it
delivered (``delivered_paced``, ``delivered_burst``: received / sent, the lowest over the runs), and
dora's throughput is the measured messages it received over the time from the first measured send
to the last arrival (a rate over its arrivals alone would count the few messages left in its queue
at the end, which arrive back to back).
Across processes, vgr's 1.2 MB payloads are built by the source in an array of ``ctx.loan`` (already in
its port's pool: sent without a copy; the same stamp, then the same body copy as ``make_payload``)
and reach the sink's handler as read-only numpy views of that memory (engine.transport.shm_views: a
descriptor over zenoh, no copy on receive),
and the sink's input is handed over on zenoh's receive thread (engine.run.remote_input: the sink
calls no service and publishes nothing to another process), as dora hands its Python nodes an
Arrow view of its shared memory.
dora has no in-process row (``dora_in_process`` says why). For payloads of at least
engine.transport.shm.SHM_MIN_BYTES, ``vgr_noshm`` is vgr with ``zenoh: {shared_memory: false}`` (every byte
through the unix socket), the A/B of vgr's shared memory (``shm_ab``).

Every process of every row runs with the C allocator settings a vgr run sets for itself
(engine.run.process_memory.keep_freed_memory: glibc keeps freed heap memory instead of unmapping it),
the raw zenoh processes and the dora nodes included, so no row gains or loses by them. Without
them the 1.2 MB rows were bimodal from process to process (vgr: 480-660 us or 1400-1950 us).

For 64 B and 4 KiB across processes a further row, ``typed_floor`` (benchmarks/wire_floor.py), gives the
throughput of vgr's codec alone: the same Blobs built, encoded, packed 64 to a zenoh sample, decoded
and handed to the sink's code in the receiving process, with no engine at all. An engine delivering
typed messages through this codec cannot beat it; ``typed_floor_throughput_ratio`` = that row / raw.

Usage: ``python benchmarks/engine_overhead.py [--quick] [--repeat N] [--out FILE]``; writes
benchmarks/results/engine_overhead.json (``--quick``: engine_overhead_quick.json, git-ignored).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(HERE), str(ROOT)]

import dora_peer  # noqa: E402
from bench_stages import make_payload, pace  # noqa: E402
from bench_zenoh import free_port, peer_session  # noqa: E402
from overhead_ratios import dora_ratios, paired, print_ratios, raw_ratios  # noqa: E402
from wire_floor import BATCH, floor_subscriber_main, send_batched  # noqa: E402

from engine.run.process_memory import keep_freed_memory  # noqa: E402
from engine.transport.shm import SHM_MIN_BYTES  # noqa: E402
from engine.transport.shm_views import VIEW_MIN_BYTES  # noqa: E402

BENCH_KEY = "bench/data"  # key of the raw and typed-floor runs
SIZES = {"64B": 64, "4KiB": 4096, "1.2MB": 1_200_000}
FLOOR_MAX_SIZE = 4096  # the typed floor row is measured for the small payloads (the targets they miss)
WARMUP = 20


def session(listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Session:
    return peer_session(listen, connect)


def summarize(
    lat_ns: list[int],
    arrivals_ns: list[int],
    size: int,
    cpu_s: float | None = None,
    lat_entry_ns: list[int] | None = None,
    sent_received: tuple[int, int] | None = None,
    since_ns: int | None = None,
) -> dict[str, float]:
    """Latency percentiles, messages per second at the receiver and CPU per message of one run;
    *since_ns*: the rate is taken from then (the first measured send) to the last arrival, for a
    receiver that may drop (dora): its few last messages can arrive back to back."""
    lat = np.asarray(lat_ns, dtype=float) / 1e3
    out: dict[str, float] = {}
    if sent_received:
        out["delivered"] = sent_received[1] / sent_received[0]
    if lat_entry_ns:
        out["p50_entry_us"] = float(np.median(np.asarray(lat_entry_ns, dtype=float))) / 1e3
    if cpu_s is not None and len(arrivals_ns):
        out["cpu_us_per_msg"] = cpu_s / len(arrivals_ns) * 1e6
    if len(lat):
        out |= {
            "p50_us": float(np.median(lat)),
            "p90_us": float(np.percentile(lat, 90)),
            "p99_us": float(np.percentile(lat, 99)),
            "n": len(lat),
        }
    if since_ns is not None and arrivals_ns:
        span, n = (arrivals_ns[-1] - since_ns) / 1e9, len(arrivals_ns)
    else:
        span = (arrivals_ns[-1] - arrivals_ns[0]) / 1e9 if len(arrivals_ns) > 1 else 0.0
        n = len(arrivals_ns) - 1
    rate = n / span if span > 0 else 0.0  # (dora may deliver one message or none)
    out |= {"msg_per_s": rate, "MB_per_s": rate * size / 1e6}
    return out


# --------------------------------------------------------------------------- raw zenoh


class RawReceiver:
    """Subscriber callback of the raw runs: latency, arrival time and process CPU time."""

    def __init__(self, total: int) -> None:
        self.lat: list[int] = []  # to the callback holding the payload bytes
        self.lat_entry: list[int] = []  # to the callback's entry
        self.arr: list[int] = []
        self.cpu = [0.0, 0.0]
        self.n = 0
        self.total = total
        self.done = threading.Event()

    def __call__(self, sample: zenoh.Sample) -> None:
        entry = time.monotonic_ns()
        data = sample.payload.to_bytes()
        now = time.monotonic_ns()
        self.n += 1
        if self.n > WARMUP:
            sent = int.from_bytes(data[:8], "little")
            self.lat.append(now - sent)
            self.lat_entry.append(entry - sent)
            self.arr.append(now)
            if len(self.lat) == 1:
                self.cpu[0] = time.process_time()
        if self.n >= self.total:
            self.cpu[1] = time.process_time()
            self.done.set()


def raw_in_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    s = session()
    rx = RawReceiver(count + WARMUP)
    sub = s.declare_subscriber(BENCH_KEY, rx)
    pub = s.declare_publisher(BENCH_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    cpu0, cpu1 = send(pub, size, count, interval_s)
    rx.done.wait(60)  # the callback runs on zenoh-python's own thread: let it finish
    sub.undeclare()
    pub.undeclare()
    s.close()
    return summarize(rx.lat, rx.arr, size, max(cpu1, rx.cpu[1]) - cpu0, rx.lat_entry, (count + WARMUP, rx.n))


def send(pub: zenoh.Publisher, size: int, count: int, interval_s: float) -> tuple[float, float]:
    """Publish warm-up + *count* messages; process CPU time at the first measured one and at the end."""
    base = bytes(max(size, 8))
    nxt = time.perf_counter()
    cpu0 = 0.0
    for i in range(count + WARMUP):
        if i == WARMUP:
            cpu0 = time.process_time()
        if interval_s:
            nxt = pace(nxt, interval_s)
        pub.put(make_payload(base))
    return cpu0, time.process_time()


def raw_subscriber_main(endpoint: str, out: str, total: int) -> None:
    """Child process: subscribe over tcp, record, write JSON when all messages arrived."""
    s = session(connect=[endpoint])
    rx = RawReceiver(total)
    s.declare_subscriber(BENCH_KEY, rx)
    rx.done.wait(300)
    Path(out).write_text(
        json.dumps({"lat_ns": rx.lat, "lat_entry_ns": rx.lat_entry, "arrivals_ns": rx.arr, "cpu_s": rx.cpu, "n": rx.n})
    )
    s.close()


def to_child(flag: str, count: int, send_fn: Callable[[zenoh.Publisher], tuple[float, float]]) -> tuple[dict, float]:
    """Publish on BENCH_KEY with *send_fn* to a child ``python THIS --<flag> ENDPOINT OUT TOTAL`` over
    tcp/127.0.0.1 once it has subscribed: (the child's JSON record, this process's CPU seconds over
    the measured messages)."""
    port = free_port()
    s = session(listen=[f"tcp/127.0.0.1:{port}"])
    pub = s.declare_publisher(BENCH_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "child.json"
        child = subprocess.Popen(
            [sys.executable, __file__, f"--{flag}", f"tcp/127.0.0.1:{port}", str(out), str(count + WARMUP)]
        )
        deadline = time.monotonic() + 30
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)
        cpu0, cpu1 = send_fn(pub)
        child.wait(300)
        res = json.loads(out.read_text())
    pub.undeclare()
    s.close()
    return res, cpu1 - cpu0


def raw_cross_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    res, tx_cpu = to_child("raw-sub", count, lambda pub: send(pub, size, count, interval_s))
    rx_cpu = res["cpu_s"][1] - res["cpu_s"][0]
    received = (count + WARMUP, res["n"])
    return summarize(res["lat_ns"], res["arrivals_ns"], size, tx_cpu + rx_cpu, res["lat_entry_ns"], received)


def floor_subscriber_process(endpoint: str, out: str, total: int) -> None:
    """Child process of the typed floor row (benchmarks/wire_floor.py)."""
    s = session(connect=[endpoint])
    floor_subscriber_main(s.declare_subscriber(BENCH_KEY, zenoh.handlers.FifoChannel(1 << 20)), out, total, WARMUP)
    s.close()


def typed_floor_cross_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    """Throughput reference: vgr's codec, batched, without the engine (see benchmarks/wire_floor.py)."""
    assert interval_s == 0.0, "the floor row measures throughput only (batching holds paced messages back)"
    rx, tx_cpu = to_child("floor-sub", count, lambda pub: send_batched(pub, size, count, WARMUP))
    out = summarize([], rx["arrivals_ns"], size, tx_cpu + (rx["cpu_s"][1] - rx["cpu_s"][0]))
    return {k: v for k, v in out.items() if k in ("msg_per_s", "MB_per_s", "cpu_us_per_msg")}


# --------------------------------------------------------------------------- vgr


RECIPE = """
name: bench
plugins: [bench_stages]
{security}
{zenoh}
processes:
  pub: {{listen: ["{proto}/127.0.0.1:{port}"]}}
  sub: {{connect: ["{proto}/127.0.0.1:{port}"], listen: []}}
stages:
  src:  {{type: bench_source, process: {p_pub}, params: {{size: {size}, count: {count}, interval_s: {interval}, warmup: {warmup}, output: "{src_out}", loan: {loan}}}}}
  sink: {{type: bench_sink, process: {p_sub}, inputs: {{in: src.out}}, params: {{output: "{out}", warmup: {warmup}}}}}
"""


def recipe(
    tmp: str,
    processes: tuple[str, str],
    size: int,
    count: int,
    interval_s: float,
    certs: Path | None = None,
    shm: bool = True,
) -> tuple[str, Path, Path]:
    """The benchmark recipe with source and sink in *processes*, and the files where sink and source
    write their figures (in *tmp*); with *certs* (a `vgr certs make` folder), secured: TLS, mTLS and
    the access-control list built from the graph (docs/security.md); *shm* False: no shared memory."""
    out, src_out = Path(tmp) / "sink.json", Path(tmp) / "src.json"
    p_pub, p_sub = processes
    text = RECIPE.format(
        security=f'security: {{certs: "{certs}"}}' if certs else "",
        zenoh="" if shm else "zenoh: {shared_memory: false}",
        proto="tls" if certs else "tcp",
        port=free_port(),
        p_pub=p_pub,
        p_sub=p_sub,
        size=size,
        count=count,
        interval=interval_s,
        warmup=WARMUP,
        loan=str(p_pub != p_sub and size >= VIEW_MIN_BYTES).lower(),  # (across processes: a view of a loan)
        out=out,
        src_out=src_out,
    )
    return text, out, src_out


def vgr_in_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    from engine.graph import build_graph
    from engine.plugin_manager import load_registry
    from engine.recipe.model import load_recipe
    from engine.run.runner import Runner

    with tempfile.TemporaryDirectory() as tmp:
        text, out, src_out = recipe(tmp, ("main", "main"), size, count, interval_s)
        text = text.replace("processes:", "unused_processes:")
        text = "\n".join(x for x in text.splitlines() if not x.strip().startswith(("unused", "pub:", "sub:")))
        loaded = load_recipe(HERE / "bench.yaml", text=text)  # (bench_stages.py is found next to it)
        # freeze_gc as `vgr run` does in its own process (the cyclic collector's full passes over this
        # process's heap would otherwise pause the stages now and then)
        summary = Runner(build_graph(loaded, load_registry(loaded.recipe.plugins)), freeze_gc=True).run()
        assert summary.ok, summary.stop_reason
        res, src = json.loads(out.read_text()), json.loads(src_out.read_text())
    cpu = max(src["cpu_s"][1], res["cpu_s"][1]) - src["cpu_s"][0]
    return summarize(res["lat_ns"], res["arrivals_ns"], size, cpu, sent_received=(count + WARMUP, res["n"]))


_CERTS: list[Path] = []  # the development certificates of the secured rows, made once per benchmark run


def bench_certs() -> Path:
    if not _CERTS:
        from engine.security.certs import Identity, write_bundle

        folder = Path(tempfile.mkdtemp(prefix="vgr-bench-certs-")) / "certs"
        write_bundle(folder, [Identity("pub"), Identity("sub")], ca_name="vgr benchmark CA")
        _CERTS.append(folder)
    return _CERTS[0]


def vgr_secured_cross_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    """vgr_cross_process with the recipe's security: block: TLS with mTLS and the ACL."""
    return vgr_cross_process(size, count, interval_s, certs=bench_certs())


def vgr_noshm_cross_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    """vgr_cross_process with shared memory off: every payload through the unix socket."""
    return vgr_cross_process(size, count, interval_s, shm=False)


def dora_cross_process(size: int, count: int, interval_s: float) -> dict[str, float]:
    """The same two stages as a dora-rs dataflow of two Python nodes (benchmarks/dora_peer.py)."""
    r = dora_peer.run_dataflow(size, count, interval_s, WARMUP)
    sent_received = (r["sent"], r["received"])
    return summarize(r["lat_ns"], r["arrivals_ns"], size, r["cpu_s"], sent_received=sent_received, since_ns=r["t0_ns"])


def vgr_cross_process(
    size: int, count: int, interval_s: float, certs: Path | None = None, shm: bool = True
) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    env["VGR_PLUGIN_PATH"] = str(HERE)  # the recipe names bench_stages, which lives here
    with tempfile.TemporaryDirectory() as tmp:
        text, out, src_out = recipe(tmp, ("pub", "sub"), size, count, interval_s, certs, shm)
        recipe_file = Path(tmp) / "bench.yaml"
        recipe_file.write_text(text)
        # no recording: the recorder's cost is measured by benchmarks/record_replay.py, and the in-process
        # runs here have none either
        cmd = [
            sys.executable,
            "-m",
            "engine.cli.main",
            "run",
            str(recipe_file),
            "--no-progress",
            "--no-record",
            "--process",
        ]
        sub = subprocess.Popen([*cmd, "sub"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        pub = subprocess.Popen([*cmd, "pub"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        _, err_pub = pub.communicate(timeout=600)
        _, err_sub = sub.communicate(timeout=600)
        if pub.returncode or sub.returncode:
            raise RuntimeError(f"vgr processes failed: {err_pub}\n{err_sub}")
        res, src = json.loads(out.read_text()), json.loads(src_out.read_text())
    cpu = (src["cpu_s"][1] - src["cpu_s"][0]) + (res["cpu_s"][1] - res["cpu_s"][0])
    return summarize(res["lat_ns"], res["arrivals_ns"], size, cpu, sent_received=(count + WARMUP, res["n"]))


# --------------------------------------------------------------------------- main


def machine() -> dict[str, object]:
    cpu = ""
    with contextlib.suppress(OSError, StopIteration):
        cpu = next(
            x.split(":", 1)[1].strip()
            for x in Path("/proc/cpuinfo").read_text().splitlines()
            if x.startswith("model name")
        )
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "zenoh": getattr(zenoh, "__version__", "1.x"),
        "platform": platform.platform(),
    }


def median_of(runs: list[dict[str, float]]) -> dict[str, float]:
    keys = set().union(*runs)
    return {k: statistics.median(r[k] for r in runs if k in r) for k in sorted(keys)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer messages and repetitions (smoke test)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, help="result file (default benchmarks/results/engine_overhead[_quick].json)")
    ap.add_argument("--raw-sub", nargs=3, metavar=("ENDPOINT", "OUT", "TOTAL"), help=argparse.SUPPRESS)
    ap.add_argument("--floor-sub", nargs=3, metavar=("ENDPOINT", "OUT", "TOTAL"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    keep_freed_memory()  # every row on the allocator settings a vgr run has (see the module docstring)
    if args.raw_sub:
        raw_subscriber_main(args.raw_sub[0], args.raw_sub[1], int(args.raw_sub[2]))
        return
    if args.floor_sub:
        floor_subscriber_process(args.floor_sub[0], args.floor_sub[1], int(args.floor_sub[2]))
        return
    t_start = time.monotonic()
    repeat = 1 if args.quick else args.repeat
    plan = {  # size -> (latency count, pacing interval, throughput count)
        "64B": (2000, 0.001, 20000),
        "4KiB": (2000, 0.001, 20000),
        "1.2MB": (300, 0.005, 600),
    }
    if args.quick:
        plan = {k: (max(100, v[0] // 10), v[1], max(60, v[2] // 10)) for k, v in plan.items()}
    topologies = {
        "in_process": {"raw_zenoh": raw_in_process, "vgr": vgr_in_process},
        "cross_process": {
            "raw_zenoh": raw_cross_process,
            "vgr": vgr_cross_process,
            "vgr_secured": vgr_secured_cross_process,
            "vgr_noshm": vgr_noshm_cross_process,  # (large payloads only: the A/B of shared memory)
            "dora": dora_cross_process,
        },
    }
    results: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
    floor_runs: dict[str, list[dict[str, float]]] = {}
    run_ratios: dict[str, dict[str, list[float]]] = {}  # vgr / raw of each pair of alternated runs
    dora_runs: dict[str, dict[str, list[float]]] = {}  # vgr / dora of each pair of alternated runs
    for topo, all_fns in topologies.items():
        for label, size in SIZES.items():
            fns = {who: fn for who, fn in all_fns.items() if who != "vgr_noshm" or size >= SHM_MIN_BYTES}
            n_lat, interval, n_tp = plan[label]
            lat_runs: dict[str, list[dict[str, float]]] = {who: [] for who in fns}
            tp_runs: dict[str, list[dict[str, float]]] = {who: [] for who in fns}
            for _ in range(repeat):  # raw and vgr alternate: load drifts hit both alike
                for who, fn in fns.items():
                    lat_runs[who].append(fn(size, n_lat, interval))
                for who, fn in fns.items():
                    tp_runs[who].append(fn(size, n_tp, 0.0))
                if topo == "cross_process" and size <= FLOOR_MAX_SIZE:
                    floor_runs.setdefault(label, []).append(typed_floor_cross_process(size, n_tp, 0.0))
            run_ratios[f"{topo}/{label}"] = paired(lat_runs, tp_runs, "raw_zenoh")
            if "dora" in fns:
                dora_runs[f"{topo}/{label}"] = paired(lat_runs, tp_runs, "dora")
            for who in fns:
                lat, tp = median_of(lat_runs[who]), median_of(tp_runs[who])
                row = {k: v for k, v in lat.items() if k.endswith("_us") or k == "n"}  # (p50_entry_us: raw only)
                row |= {k: v for k, v in tp.items() if k in ("msg_per_s", "MB_per_s", "cpu_us_per_msg")}
                row["delivered_paced"] = min(r["delivered"] for r in lat_runs[who])  # received / sent, worst run
                row["delivered_burst"] = min(r["delivered"] for r in tp_runs[who])
                results.setdefault(topo, {}).setdefault(label, {})[who] = row
                nan = float("nan")  # (a row that received no measured message: dora can drop them all)
                print(
                    f"{topo:14s} {label:6s} {who:10s} p50 {row.get('p50_us', nan):8.1f} us  "
                    f"p99 {row.get('p99_us', nan):8.1f} us  "
                    f"{row['msg_per_s']:10.0f} msg/s  {row['MB_per_s']:8.1f} MB/s  "
                    f"cpu {row.get('cpu_us_per_msg', nan):8.1f} us/msg  "
                    f"delivered {row['delivered_paced']:.3f} / {row['delivered_burst']:.3f}",
                    flush=True,
                )
    for label, runs in floor_runs.items():
        row = median_of(runs)
        results["cross_process"][label]["typed_floor"] = row
        print(
            f"{'cross_process':14s} {label:6s} {'floor':10s} {'':33s}{row['msg_per_s']:10.0f} msg/s  "
            f"{row['MB_per_s']:8.1f} MB/s  cpu {row['cpu_us_per_msg']:8.1f} us/msg   (codec, {BATCH} per sample, no engine)",
            flush=True,
        )
    ratios = raw_ratios(results, run_ratios)
    elapsed = time.monotonic() - t_start
    doc = {
        "benchmark": "engine_overhead",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "machine": machine(),
        "method": __doc__,
        "repeat": repeat,
        "plan": {k: {"latency_messages": v[0], "pacing_s": v[1], "throughput_messages": v[2]} for k, v in plan.items()},
        "results": results,
        "ratios_vgr_over_raw": ratios,
        "ratios_vgr_over_dora": dora_ratios(results, dora_runs),
        "dora_in_process": dora_peer.IN_PROCESS_NOTE,
        "duration_s": round(elapsed, 1),
    }
    out = args.out or HERE / "results" / ("engine_overhead_quick.json" if args.quick else "engine_overhead.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2))
    print_ratios(ratios, doc["ratios_vgr_over_dora"])
    print(f"written {out} after {elapsed:.0f} s")


if __name__ == "__main__":
    main()
