"""The floor of typed small messages between two processes: vgr's codec without the engine.

Used by benchmarks/engine_overhead.py as a reference row next to raw zenoh and vgr. The sender
builds each message as a stage does (a ``Blob`` of the same timestamped payload), encodes it with
vgr's codec (``engine.messages.codec.encode_payload`` and the port envelope) and packs ``BATCH`` of them into
one zenoh sample in engine.transport.wire's batch format — always, where vgr batches only while a producer
bursts — so zenoh's per-sample costs (the put, the transmit thread's wake-up, the receive channel)
are spread over many messages. The receiving process decodes every message with the codec
(``decode_payload``) and hands it to a handler doing what ``bench_sink`` does. No engine: no
stage locks, sequence checks, counters, observers or threads of ours.

Whatever an engine that delivers typed messages through this codec adds, it cannot go faster than
this row; comparing it with raw zenoh (bytes in, bytes out, no types) shows how much of the
small-message throughput target is the price of typed messages in CPython rather than of the
engine.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import zenoh
from bench_stages import make_payload

from engine.messages import Blob, codec
from engine.transport.wire import BATCH_ENVELOPE, iter_batch, pack_batch

BATCH = 64  # messages per zenoh sample


def floor_subscriber_main(sub: zenoh.Subscriber, out: str, total: int, warmup: int) -> None:
    """Child process: receive batches from *sub* (a FIFO channel subscriber), decode every message,
    note latency, arrivals and CPU time, write them to *out* as JSON."""
    channel, decode = sub.handler, codec.decode_payload
    unpack = codec.DataFormat(Blob.TYPE).unpack
    lat: list[int] = []
    arrivals: list[int] = []
    cpu = [0.0, 0.0]
    n = 0
    while n < total:
        sample = channel.try_recv() or channel.recv()
        assert sample.attachment is not None and sample.attachment.to_bytes() == BATCH_ENVELOPE
        for env, payload in iter_batch(sample.payload.to_bytes()):
            _, seq, _, _ = unpack(env)
            msg = decode(Blob, payload)
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


def send_batched(pub: zenoh.Publisher, size: int, count: int, warmup: int) -> tuple[float, float]:
    """Publish warm-up + *count* Blobs of *size* bytes as fast as possible, BATCH to a sample;
    process CPU time at the first measured message and at the end."""
    base = bytes(max(size, 8))
    fmt = codec.DataFormat(Blob.TYPE)
    encode, pack, head, name, put = codec.encode_payload, fmt.pack, fmt.head, fmt.name, pub.put
    batch: list[tuple[bytes, bytes]] = []
    cpu0 = 0.0
    for i in range(count + warmup):
        if i == warmup:
            cpu0 = time.process_time()
        msg = Blob(data=make_payload(base))
        msg.stamp_ns = time.monotonic_ns()
        msg.seq = i + 1
        batch.append((pack(head, msg.seq, msg.stamp_ns, name), encode(msg)))
        if len(batch) >= BATCH:
            put(pack_batch(batch), attachment=BATCH_ENVELOPE)
            batch.clear()
    if batch:
        put(pack_batch(batch), attachment=BATCH_ENVELOPE)
    return cpu0, time.process_time()
