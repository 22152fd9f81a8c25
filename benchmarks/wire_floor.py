"""The floor of typed small messages between two processes: vgr's codec without the engine.

Used by benchmarks/engine_overhead.py as a reference row next to raw zenoh and vgr. The sender
builds each message as a stage does (a ``Blob`` of the same timestamped payload), encodes it with
vgr's codec (``engine.codec.encode_payload``) and, unlike vgr, packs ``BATCH`` of them into one zenoh
sample, so zenoh's per-sample costs (the put, the transmit thread's wake-up, the receive channel) are
spread over many messages. The receiving process decodes every message with the codec
(``decode_payload``) and hands it to a handler doing what ``bench_sink`` does. No engine: no
stage locks, sequence checks, counters, observers or threads of ours.

Whatever an engine that delivers typed messages through this codec adds, it cannot go faster than
this row; comparing it with raw zenoh (bytes in, bytes out, no types) shows how much of the
small-message throughput target is the price of typed messages in CPython rather than of the
engine.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import zenoh
from bench_stages import make_payload

from engine import codec
from engine.messages import Blob

BATCH = 64  # messages per zenoh sample
_RECORD = struct.Struct("<QI")  # seq, payload length; then the payload


def floor_subscriber_main(
    endpoint: str, out: str, total: int, warmup: int, session_fn: Callable[..., zenoh.Session]
) -> None:
    """Child process: receive batches, decode every message, note latency, arrivals and CPU time."""
    s = session_fn(connect=[endpoint])
    sub = s.declare_subscriber("bench/floor", zenoh.handlers.FifoChannel(1 << 20))
    channel, decode, unpack, head = sub.handler, codec.decode_payload, _RECORD.unpack_from, _RECORD.size
    lat: list[int] = []
    arrivals: list[int] = []
    cpu = [0.0, 0.0]
    n = 0
    while n < total:
        sample = channel.try_recv() or channel.recv()
        buf = sample.payload.to_bytes()
        view, off, end = memoryview(buf), 0, len(buf)
        while off < end:
            seq, size = unpack(buf, off)
            off += head
            msg = decode(Blob, view[off : off + size])
            off += size
            msg.seq = seq
            # the handler: what bench_sink.on_message does
            now = time.monotonic_ns()
            n += 1
            if n <= warmup:
                continue
            lat.append(now - int.from_bytes(bytes(msg.data[:8]), "little"))
            arrivals.append(now)
            if len(lat) == 1:
                cpu[0] = time.process_time()
    cpu[1] = time.process_time()
    Path(out).write_text(json.dumps({"lat_ns": lat, "arrivals_ns": arrivals, "cpu_s": cpu}))
    s.close()


def floor_cross_process(
    size: int, count: int, warmup: int, endpoint_port: int, session_fn: Callable[..., zenoh.Session], script: str
) -> dict[str, object]:
    """Publish warm-up + *count* Blobs of *size* bytes as fast as possible, BATCH per sample, to a
    child process started as ``python SCRIPT --floor-sub ENDPOINT OUT TOTAL``; returns the child's
    record and this process's CPU seconds over the measured messages."""
    endpoint = f"tcp/127.0.0.1:{endpoint_port}"
    s = session_fn(listen=[endpoint])
    pub = s.declare_publisher("bench/floor", congestion_control=zenoh.CongestionControl.BLOCK)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "floor.json"
        child = subprocess.Popen([sys.executable, script, "--floor-sub", endpoint, str(out), str(count + warmup)])
        deadline = time.monotonic() + 30
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)
        base = bytes(max(size, 8))
        encode, pack, put = codec.encode_payload, _RECORD.pack, pub.put
        parts: list[bytes] = []
        cpu0 = 0.0
        for i in range(count + warmup):
            if i == warmup:
                cpu0 = time.process_time()
            msg = Blob(data=make_payload(base))
            msg.stamp_ns = time.monotonic_ns()
            msg.seq = i + 1
            payload = encode(msg)
            parts += (pack(msg.seq, len(payload)), payload)
            if len(parts) >= 2 * BATCH:
                put(b"".join(parts))
                parts.clear()
        if parts:
            put(b"".join(parts))
        cpu1 = time.process_time()
        child.wait(300)
        res = json.loads(out.read_text())
    pub.undeclare()
    s.close()
    return {"receiver": res, "sender_cpu_s": cpu1 - cpu0}
