"""Which route takes a small message from one Python process to a thread of another process on the
same host fastest: the measurements behind engine.transport.local_link.

One sender process (this one) and one receiver process (a child). Latency is one-way, from
``time.monotonic_ns()`` written into the payload's first 8 bytes just before the payload is built
to the moment the receiving Python code holds the bytes and has read the stamp; paced 1 ms, so
every message finds both processes idle (a camera frame, a robot's request), median over the
measured messages. Routes:

* ``zenoh_tcp``: a zenoh put, the subscriber's callback on zenoh's receive thread
  (``zenoh.handlers.Callback(..., indirect=False)``: no hand-over), over tcp/127.0.0.1;
* ``zenoh_unix``: the same over a unix socket (``unixsock-stream``, vgr's default between the
  processes of a run);
* ``vgr_link``: engine.transport.local_link itself: the sender's ``LinkSender.send`` (one
  ``sendmsg`` on a unix stream socket), the receiver's thread reading ``FrameReader.frames()``;
* ``iceoryx2`` (when the ``iceoryx2`` package imports): the payload loaned from and sent through an
  iceoryx2 publish-subscribe service, then an event notification; the receiver's thread waits on
  the event's listener and takes the samples (what it received of what was sent: ``delivered``).

The routes alternate run by run (``--repeat``, default 5). Every process runs with the C
allocator settings of a vgr run (engine.run.process_memory). Usage:
``python benchmarks/local_link.py [--repeat N] [--out FILE]``; writes results/local_link.json.

``--leak N``: the leak check of a link over N messages (tests/engine_core/test_local_link.py runs it
over 20 000): a ``LinkSender`` thread sends N frames (every 100th a 700 kB payload, larger than one
read, the rest 64 B) through a unix socket pair to a ``FrameReader``, which checks each; then the
open file descriptors, threads and resident memory before and after, and whether every frame came
whole and in order; writes results/local_link_leak.json (``--out`` for another file).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh
from bench_stages import make_payload, pace
from bench_zenoh import free_port, peer_session

HERE = Path(__file__).resolve().parent
KEY = "bench/link"
WARMUP = 20
SIZES = {"64B": 64, "4KiB": 4096}
COUNT, INTERVAL_S = 2000, 0.001
DELIVERED: dict[str, list[float]] = {}  # route -> received / sent of each run


class Record:
    def __init__(self, total: int) -> None:
        self.lat: list[int] = []
        self.n = 0
        self.total = total
        self.done = threading.Event()

    def note(self, data: bytes | memoryview) -> None:
        now = time.monotonic_ns()
        self.n += 1
        if self.n > WARMUP:
            self.lat.append(now - int.from_bytes(bytes(data[:8]), "little"))
        if self.n >= self.total:
            self.done.set()


# --------------------------------------------------------------------------- receiver (a child)


def receiver(route: str, where: str, out: str, total: int) -> None:
    rec = Record(total)
    keep: list[Any] = []
    if route.startswith("zenoh"):
        s = peer_session(connect=[where])
        cb = zenoh.handlers.Callback(lambda sample: rec.note(sample.payload.to_bytes()), indirect=False)
        keep += [s, s.declare_subscriber(KEY, cb)]
    elif route == "vgr_link":
        from engine.transport.local_link import FrameReader

        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.connect(where)

        def read() -> None:
            for _env, payload in FrameReader(sock).frames():
                rec.note(payload)

        threading.Thread(target=read, daemon=True).start()
    elif route == "iceoryx2":
        iox, node, data, event = iox_services()
        keep += [node, data, event]
        sub, listener = data.subscriber_builder().create(), event.listener_builder().create()
        threading.Thread(target=iox_reader, args=(iox, sub, listener, rec), daemon=True).start()
    print("ready", flush=True)
    seen = -1  # until all arrived, or nothing more for 3 s (a route that lost some: ``delivered`` says)
    while not rec.done.wait(3.0) and rec.n != seen:
        seen = rec.n
    Path(out).write_text(json.dumps({"lat_ns": rec.lat, "n": rec.n}))


def iox_services() -> tuple[Any, Any, Any, Any]:
    import ctypes

    import iceoryx2 as iox

    node = iox.NodeBuilder.new().create(iox.ServiceType.Ipc)
    name = f"vgr/bench/link/{os.environ.get('VGR_BENCH_IOX', '0')}"
    data = (
        node.service_builder(iox.ServiceName.new(name))
        .publish_subscribe(iox.Slice[ctypes.c_uint8])
        .subscriber_max_buffer_size(64)
        .open_or_create()
    )
    event = node.service_builder(iox.ServiceName.new(f"{name}/event")).event().open_or_create()
    return iox, node, data, event


def iox_reader(iox: Any, sub: Any, listener: Any, rec: Record) -> None:
    while not rec.done.is_set():
        for _ in listener.timed_wait(iox.Duration.from_secs(1)):
            while (sample := sub.receive()) is not None:
                rec.note(sample.payload().as_memory_view().cast("B"))
                sample.delete()


# --------------------------------------------------------------------------- sender (this process)


def run(route: str, size: int) -> float:
    """One run of *route*: the receiver's p50 in us."""
    total = COUNT + WARMUP
    base = bytes(max(size, 8))
    with tempfile.TemporaryDirectory(prefix="vgr-ll-") as tmp:
        out = str(Path(tmp) / "rx.json")
        keep: list[Any] = []
        if route == "zenoh_tcp":
            where = f"tcp/127.0.0.1:{free_port()}"
        elif route == "zenoh_unix":
            where = f"unixsock-stream/{tmp}/z.sock"
        else:
            where = f"{tmp}/l.sock"
        if route.startswith("zenoh"):
            s = peer_session(listen=[where])
            pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
            keep.append(s)

            def put() -> None:
                pub.put(make_payload(base))
        elif route == "vgr_link":
            from engine.transport.local_link import LinkSender

            srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            srv.bind(where)
            srv.listen(1)
            keep.append(srv)
        else:
            os.environ["VGR_BENCH_IOX"] = str(os.getpid())
            _iox, node, data, event = iox_services()
            publisher = data.publisher_builder().initial_max_slice_len(size).create()
            notifier = event.notifier_builder().create()
            keep += [node, data, event]

            def put() -> None:
                payload = make_payload(base)
                sample = publisher.loan_slice_uninit(size)
                sample.payload().as_memory_view().cast("B")[:] = payload
                sample.assume_init().send()
                notifier.notify()

        child = subprocess.Popen(
            [sys.executable, __file__, "--rx", route, where, out, str(total)],
            env=dict(os.environ),
            stdout=subprocess.PIPE,
            text=True,
        )
        if route == "vgr_link":
            conn, _ = srv.accept()
            link = LinkSender(conn, "bench")

            def put() -> None:
                link.send(b"", make_payload(base))

        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        if route.startswith("zenoh"):
            deadline = time.monotonic() + 30
            while not pub.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.01)
        time.sleep(0.3)
        nxt = time.perf_counter()
        for _ in range(total):
            nxt = pace(nxt, INTERVAL_S)
            put()
        child.wait(120)
        res = json.loads(Path(out).read_text())
        for k in keep:
            if hasattr(k, "close"):
                k.close()
    DELIVERED.setdefault(route, []).append(res["n"] / total)
    return statistics.median(res["lat_ns"]) / 1e3


def resident_kb() -> int:
    line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith("VmRSS:"))
    return int(line.split()[1])


def leak_run(n: int) -> dict[str, Any]:
    """The leak check over *n* messages (see the module docstring)."""
    from engine.transport.local_link import FrameReader, LinkSender

    small, large = bytes(range(64)), bytes(700_000)

    def one_link(count: int) -> int:
        a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        link = LinkSender(a, "leak")

        def send() -> None:
            for k in range(count):
                link.send(k.to_bytes(8, "little"), large if k % 100 == 99 else small)
            link.close()

        writer = threading.Thread(target=send)
        writer.start()
        good = 0
        for k, (env, payload) in enumerate(FrameReader(b).frames()):
            want = large if k % 100 == 99 else small
            good += int.from_bytes(env, "little") == k and len(payload) == len(want) and payload[-1] == want[-1]
        writer.join(60)
        b.close()
        return good

    one_link(2000)  # warm: buffers and the allocator's pools exist
    before = {"fds": len(os.listdir("/proc/self/fd")), "threads": threading.active_count(), "rss_kb": resident_kb()}
    t0 = time.monotonic()
    good = one_link(n)
    took = time.monotonic() - t0
    after = {"fds": len(os.listdir("/proc/self/fd")), "threads": threading.active_count(), "rss_kb": resident_kb()}
    grown = after["rss_kb"] - before["rss_kb"]
    return {
        "messages": n,
        "whole_and_in_order": good,
        "before": before,
        "after": after,
        "rss_growth_kb": grown,
        "us_per_message": round(took / n * 1e6, 2),
        "leaked": good != n or after["fds"] != before["fds"] or after["threads"] != before["threads"] or grown > 8192,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "local_link.json")
    ap.add_argument("--rx", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--leak", type=int, metavar="N", help="the leak check over N messages instead")
    args = ap.parse_args()
    sys.path[:0] = [str(HERE.parent)]
    from engine.run.process_memory import keep_freed_memory

    keep_freed_memory()
    if args.rx:
        receiver(args.rx[0], args.rx[1], args.rx[2], int(args.rx[3]))
        return
    if args.leak:
        leak = leak_run(args.leak)
        out = args.out if args.out != ap.get_default("out") else HERE / "results" / "local_link_leak.json"
        out.write_text(json.dumps(leak, indent=2))
        print(json.dumps(leak))
        return
    routes = ["zenoh_tcp", "zenoh_unix", "vgr_link"]
    try:
        import iceoryx2  # noqa: F401

        routes.append("iceoryx2")
    except ImportError:
        pass
    t0 = time.monotonic()
    runs: dict[str, dict[str, list[float]]] = {}
    for label, size in SIZES.items():
        for _ in range(args.repeat):
            for route in routes:
                p50 = run(route, size)
                runs.setdefault(label, {}).setdefault(route, []).append(round(p50, 1))
                print(f"{label:5s} {route:11s} p50 {p50:8.1f} us", flush=True)
    doc = {
        "benchmark": "local_link",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "method": __doc__,
        "messages": COUNT,
        "pacing_s": INTERVAL_S,
        "repeat": args.repeat,
        "p50_us_runs": runs,
        "p50_us": {k: {r: statistics.median(v) for r, v in rows.items()} for k, rows in runs.items()},
        "delivered_lowest": {route: min(v) for route, v in DELIVERED.items()},
        "duration_s": round(time.monotonic() - t0, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2))
    print(json.dumps(doc["p50_us"], indent=1))


if __name__ == "__main__":
    main()
