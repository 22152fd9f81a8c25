"""Which route gives a Python stage of another process a view of a large payload, and which hand-over
gives a small one at raw zenoh's pace: the measurements behind engine.transport.shm_ring.

One sender process (this one) and one receiver process (a child), over tcp/127.0.0.1 as the engine
overhead benchmark has them. Latency is one-way, from ``time.monotonic_ns()`` written into the
payload's first 8 bytes just before the payload is written to the moment the receiving code holds
the data (bytes or a view) and has read the stamp; paced, median over the measured messages.

Large payloads (1.2 MB, paced 5 ms):

* ``zenoh_shm_copy``: what vgr did before: a buffer of a zenoh ``ShmProvider`` put on zenoh, the
  receiver takes the sample from a FIFO channel and copies it out (``ZBytes.to_bytes()``: zenoh-python
  has no buffer protocol);
* ``vgr_memfd_view``: a pool vgr owns (one ``memfd``), the payload written into a block of it, a
  40-byte descriptor put on zenoh; the receiver maps the pool once (``/proc/<pid>/fd/<fd>``) and makes
  a read-only numpy view of the block, then marks the block released in the pool's header;
* ``iceoryx2_view`` (when the ``iceoryx2`` package imports): the payload loaned from and sent through an
  iceoryx2 publish-subscribe service, a descriptor put on zenoh to wake the receiver (and keep the
  order with the port's small messages, which stay on zenoh), the receiver takes the iceoryx2
  sample and makes a numpy view of it (``Slice.as_memory_view``).

Every process runs with the C allocator settings of a vgr run (engine.run.process_memory).

Small payloads (64 B, paced 1 ms), three hand-overs of the same zenoh sample:

* ``callback_thread``: a plain Python callback (zenoh-python runs it on a thread of its own, fed
  through a channel: what the raw zenoh row of benchmarks/engine_overhead.py measures);
* ``fifo_pump``: a FIFO channel read by a Python thread (what vgr's remote input did);
* ``rx_thread``: ``zenoh.handlers.Callback(fn, indirect=False)``: the callback runs on zenoh's own
  receive thread, no hand-over at all.

The rows of each size alternate run by run (``--repeat``, default 3). Usage:
``python benchmarks/shm_view.py [--repeat N] [--out FILE]``; writes results/shm_view.json.

``--leak N``: the leak check of engine.transport.shm_views over N messages (tests/engine_core/
test_shm_views.py runs it over 20 000): each message placed in a pool, viewed, read and dropped;
then blocks in flight, file descriptors and mappings before and after, and the mappings left once
pool and reader are closed; writes results/shm_view_leak.json.
"""

from __future__ import annotations

import argparse
import json
import mmap
import os
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.shm
from bench_zenoh import free_port, peer_session

HERE = Path(__file__).resolve().parent
KEY = "bench/view"
WARMUP = 20
DESC = struct.Struct("<iiQQQ")  # pid, fd, offset, length, slot
POOL = 64 * 1024 * 1024
HEADER = 4096


def session(listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Session:
    return peer_session(listen, connect, {"transport/shared_memory/enabled": True})  # (as a vgr session has it)


def pace(slot: float, interval_s: float) -> float:
    slot += interval_s
    while (d := slot - time.perf_counter()) > 0:
        time.sleep(d)
    return slot


# --------------------------------------------------------------------------- receiver (child)


class Record:
    def __init__(self, total: int) -> None:
        self.lat: list[int] = []
        self.n = 0
        self.total = total
        self.done = threading.Event()

    def note(self, stamp: int) -> None:
        now = time.monotonic_ns()
        self.n += 1
        if self.n > WARMUP:
            self.lat.append(now - stamp)
        if self.n >= self.total:
            self.done.set()


def receiver(route: str, endpoint: str, out: str, total: int) -> None:
    s = session(connect=[endpoint])
    rec = Record(total)
    from_bytes = int.from_bytes
    if route == "callback_thread":
        s.declare_subscriber(KEY, lambda sample: rec.note(from_bytes(sample.payload.to_bytes()[:8], "little")))
    elif route == "rx_thread":
        cb = zenoh.handlers.Callback(
            lambda sample: rec.note(from_bytes(sample.payload.to_bytes()[:8], "little")), indirect=False
        )
        s.declare_subscriber(KEY, cb)
    elif route in ("fifo_pump", "zenoh_shm_copy"):
        sub = s.declare_subscriber(KEY, zenoh.handlers.FifoChannel(1 << 16))
        threading.Thread(
            target=lambda: [
                rec.note(from_bytes(sub.handler.recv().payload.to_bytes()[:8], "little")) for _ in range(total)
            ],
            daemon=True,
        ).start()
    elif route == "vgr_memfd_view":
        sub = s.declare_subscriber(KEY, zenoh.handlers.FifoChannel(1 << 16))
        threading.Thread(target=memfd_reader, args=(sub.handler, rec, total), daemon=True).start()
    elif route == "iceoryx2_view":
        sub = s.declare_subscriber(KEY, zenoh.handlers.FifoChannel(1 << 16))
        threading.Thread(target=iox_reader, args=(sub.handler, rec, total), daemon=True).start()
    rec.done.wait(120)
    Path(out).write_text(json.dumps({"lat_ns": rec.lat, "n": rec.n}))
    s.close()


def memfd_reader(channel: Any, rec: Record, total: int) -> None:
    maps: dict[tuple[int, int], tuple[mmap.mmap, np.ndarray]] = {}
    for _ in range(total):
        sample = channel.recv()
        pid, fd, off, n, slot = DESC.unpack(sample.payload.to_bytes())
        got = maps.get((pid, fd))
        if got is None:
            f = os.open(f"/proc/{pid}/fd/{fd}", os.O_RDWR)
            data = mmap.mmap(f, POOL - HEADER, offset=HEADER, prot=mmap.PROT_READ)
            head = mmap.mmap(f, HEADER)
            os.close(f)
            got = maps[(pid, fd)] = (data, np.frombuffer(head, dtype=np.uint64))
        view = np.frombuffer(got[0], dtype=np.uint8, count=n, offset=off)  # read-only, no copy
        rec.note(int.from_bytes(view[:8].tobytes(), "little"))
        del view
        got[1][slot] += 1  # released


def iox_reader(channel: Any, rec: Record, total: int) -> None:
    import ctypes

    import iceoryx2 as iox

    node = iox.NodeBuilder.new().create(iox.ServiceType.Ipc)
    service = (
        node.service_builder(iox.ServiceName.new("vgr/bench/view"))
        .publish_subscribe(iox.Slice[ctypes.c_uint8])
        .open_or_create()
    )
    sub = service.subscriber_builder().create()
    for _ in range(total):
        channel.recv()
        sample = sub.receive()
        while sample is None:  # (the zenoh descriptor is put after the iceoryx2 send)
            sample = sub.receive()
        view = np.frombuffer(sample.payload().as_memory_view(), dtype=np.uint8)
        rec.note(int.from_bytes(view[:8].tobytes(), "little"))
        del view
        sample.delete()


# --------------------------------------------------------------------------- sender (this process)


def run(route: str, size: int, count: int, interval_s: float) -> float:
    port = free_port()
    s = session(listen=[f"tcp/127.0.0.1:{port}"])
    pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    put = sender_for(route, pub, size)
    out = Path(f"/tmp/vgr-shm-view-{os.getpid()}.json")
    child = subprocess.Popen(
        [sys.executable, __file__, "--rx", route, f"tcp/127.0.0.1:{port}", str(out), str(count + WARMUP)]
    )
    deadline = time.monotonic() + 30
    while not pub.matching_status.matching and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.3)
    nxt = time.perf_counter()
    for _ in range(count + WARMUP):
        nxt = pace(nxt, interval_s)
        put()
    child.wait(120)
    res = json.loads(out.read_text())
    out.unlink()
    s.close()
    return statistics.median(res["lat_ns"]) / 1e3


def sender_for(route: str, pub: zenoh.Publisher, size: int) -> Any:
    body = bytes(size)
    stamp = time.monotonic_ns
    if route in ("callback_thread", "rx_thread", "fifo_pump"):
        return lambda: pub.put(b"".join((stamp().to_bytes(8, "little"), body[8:])))
    if route == "zenoh_shm_copy":
        provider = zenoh.shm.ShmProvider.default_backend(POOL)

        def put_shm() -> None:
            provider.garbage_collect()
            buf = provider.alloc(size, zenoh.shm.JustAlloc())
            buf[0:size] = b"".join((stamp().to_bytes(8, "little"), body[8:]))
            pub.put(zenoh.ZBytes(buf))

        return put_shm
    if route == "vgr_memfd_view":
        fd = os.memfd_create("vgr-bench", os.MFD_CLOEXEC)
        os.ftruncate(fd, POOL)
        data = mmap.mmap(fd, POOL - HEADER, offset=HEADER)
        head = np.frombuffer(mmap.mmap(fd, HEADER), dtype=np.uint64)
        pid = os.getpid()
        state = {"k": 0}

        def put_memfd() -> None:  # the first block its receiver released (a pool's first fit)
            slot = next((k for k in range(8) if head[k] == state.get(k, 0)), None)
            if slot is None:
                raise RuntimeError("no block released")
            state[slot] = state.get(slot, 0) + 1
            off = slot * size
            data[off : off + 8] = stamp().to_bytes(8, "little")
            data[off + 8 : off + size] = memoryview(body)[8:]
            pub.put(DESC.pack(pid, fd, off, size, slot))

        return put_memfd
    if route == "iceoryx2_view":
        import ctypes

        import iceoryx2 as iox

        node = iox.NodeBuilder.new().create(iox.ServiceType.Ipc)
        service = (
            node.service_builder(iox.ServiceName.new("vgr/bench/view"))
            .publish_subscribe(iox.Slice[ctypes.c_uint8])
            .open_or_create()
        )
        publisher = service.publisher_builder().initial_max_slice_len(size).create()
        keep = [node, service]

        def put_iox() -> None:
            sample = publisher.loan_slice_uninit(size)
            view = sample.payload().as_memory_view().cast("B")
            view[0:8] = stamp().to_bytes(8, "little")
            view[8:size] = memoryview(body)[8:]
            sample.assume_init().send()
            pub.put(b"x", attachment=bytes(len(keep)))

        return put_iox
    raise ValueError(route)


def leak_run(n: int) -> dict[str, Any]:
    """The leak check over *n* messages (see the module docstring)."""
    import gc

    from engine.transport.shm_views import ViewPool, ViewReader

    class Peers:
        def zids(self, process: str) -> frozenset[str]:
            return frozenset({"zid"})

    def maps() -> int:
        return sum("memfd:vgr-views" in line for line in Path("/proc/self/maps").read_text().splitlines())

    body = bytes(range(256)) * 300
    pool, reader = ViewPool(Peers(), [("b", "sink", "in")], size=4 << 20), ViewReader(0)  # type: ignore[arg-type]

    def cycle(count: int) -> None:
        for k in range(count):
            placed = pool.place(b"h%d" % (k % 10), memoryview(body))
            assert placed is not None
            view = reader.payload(placed.descriptor)
            assert view[-1] == body[-1]
            del view

    cycle(200)
    before = {"fds": len(os.listdir("/proc/self/fd")), "maps": maps()}
    t0 = time.monotonic()
    cycle(n)
    took = time.monotonic() - t0
    after = {"fds": len(os.listdir("/proc/self/fd")), "maps": maps(), "in_flight": pool.in_flight()}
    reader.close()
    pool.close()
    gc.collect()
    return {
        "messages": n,
        "bytes_each": 2 + len(body),
        "before": before,
        "after": after,
        "fallbacks": pool.fallbacks,
        "maps_at_end": maps(),
        "us_per_message": round(took / n * 1e6, 2),
        "leaked": after["fds"] != before["fds"] or after["maps"] != before["maps"] or after["in_flight"] != 0,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "shm_view.json")
    ap.add_argument("--rx", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--leak", type=int, metavar="N", help="the leak check over N messages instead")
    args = ap.parse_args()
    sys.path[:0] = [str(HERE.parent)]
    from engine.run.process_memory import keep_freed_memory

    keep_freed_memory()  # the allocator settings of a vgr run, in every process (see engine_overhead.py)
    if args.rx:
        receiver(args.rx[0], args.rx[1], args.rx[2], int(args.rx[3]))
        return
    if args.leak:
        leak = leak_run(args.leak)
        (HERE / "results" / "shm_view_leak.json").write_text(json.dumps(leak, indent=2))
        print(json.dumps(leak))
        return
    try:
        import iceoryx2  # noqa: F401

        large = ["zenoh_shm_copy", "vgr_memfd_view", "iceoryx2_view"]
    except ImportError:
        large = ["zenoh_shm_copy", "vgr_memfd_view"]
    plan = {
        "1.2MB": (1_200_000, 300, 0.005, large),
        "64B": (64, 1000, 0.001, ["callback_thread", "fifo_pump", "rx_thread"]),
    }
    results: dict[str, dict[str, list[float]]] = {}
    for label, (size, count, interval, routes) in plan.items():
        for _ in range(args.repeat):
            for route in routes:
                p50 = run(route, size, count, interval)
                results.setdefault(label, {}).setdefault(route, []).append(round(p50, 1))
                print(f"{label:6s} {route:16s} p50 {p50:8.1f} us", flush=True)
    doc = {
        "benchmark": "shm_view",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "method": __doc__,
        "p50_us_runs": results,
    }
    doc["p50_us"] = {k: {r: statistics.median(v) for r, v in rows.items()} for k, rows in results.items()}
    args.out.write_text(json.dumps(doc, indent=2))
    print(json.dumps(doc["p50_us"], indent=1))


if __name__ == "__main__":
    main()
