"""Where shared memory starts to pay: one-way latency of a payload between two processes, socket vs shm.

The threshold engine.transport.shm.SHM_MIN_BYTES comes from this. For each payload size, alternated run by
run: ``socket`` (both sessions with ``transport/shared_memory/enabled`` false: the bytes cross the
unix socket) and ``shm`` (both on, the publisher's payload copied into a buffer of
engine.transport.shm.ShmPool, as engine.transport.wire does). The receiver is a child process connected over a unix
socket (vgr's default between the processes of one host); latency from ``time.monotonic_ns()``
stamped into the payload just before it is built (benchmarks/bench_stages.make_payload) to the
subscriber callback holding the bytes (``payload.to_bytes()``), p50 over ``COUNT`` paced messages
after a warm-up.

Usage: ``python benchmarks/shm_threshold.py [--repeat N]``; writes
benchmarks/results/shm_threshold.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]

from bench_results import machine, write_result  # noqa: E402
from bench_stages import make_payload, pace  # noqa: E402
from bench_zenoh import peer_session  # noqa: E402

from engine.transport.shm import ShmPool, session_entries  # noqa: E402

KEY = "bench/shm"
SIZES = [16 * 1024, 32 * 1024, 64 * 1024, 128 * 1024, 1_200_000]
COUNT, WARMUP, INTERVAL_S = 200, 20, 0.005


def session(shm: bool, listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Session:
    return peer_session(listen, connect, session_entries(shm))


def receiver_main(endpoint: str, shm: bool, total: int) -> None:
    s = session(shm, connect=[endpoint])
    lat: list[int] = []
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        lat.append(time.monotonic_ns() - int.from_bytes(data[:8], "little"))
        if len(lat) >= total:
            done.set()

    s.declare_subscriber(KEY, on_sample)
    done.wait(120)
    print(json.dumps(lat[WARMUP:]))
    s.close()


def one_run(size: int, shm: bool) -> float:
    with tempfile.TemporaryDirectory(prefix="vgr-shmt-") as tmp:
        endpoint = f"unixsock-stream/{tmp}/p.sock"
        s = session(shm, listen=[endpoint])
        pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
        child = subprocess.Popen(
            [sys.executable, __file__, "--receiver", endpoint, str(int(shm)), str(COUNT + WARMUP)],
            stdout=subprocess.PIPE,
            text=True,
        )
        while not pub.matching_status.matching:
            time.sleep(0.01)
        time.sleep(0.2)
        wrap = ShmPool().wrap if shm else (lambda p: p)
        base, nxt = bytes(size), time.perf_counter()
        for _ in range(COUNT + WARMUP):
            nxt = pace(nxt, INTERVAL_S)
            pub.put(wrap(make_payload(base)))
        lat = json.loads(child.communicate(timeout=120)[0])
        pub.undeclare()
        s.close()
    return float(np.median(lat)) / 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--receiver", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.receiver:
        receiver_main(args.receiver[0], args.receiver[1] == "1", int(args.receiver[2]))
        return
    rows: dict[str, dict[str, list[float]]] = {}
    for size in SIZES:
        runs: dict[str, list[float]] = {"socket": [], "shm": []}
        for _ in range(args.repeat):
            for way in runs:
                runs[way].append(round(one_run(size, way == "shm"), 1))
        rows[str(size)] = runs
        print(f"{size:8d} B  socket p50 {runs['socket']} us   shm p50 {runs['shm']} us", flush=True)
    write_result(
        HERE / "results" / "shm_threshold.json",
        {
            "benchmark": "shm_threshold",
            "date": time.strftime("%Y-%m-%d %H:%M:%S"),
            "machine": machine(),
            "method": __doc__,
            "p50_us_runs": rows,
        },
    )


if __name__ == "__main__":
    main()
