"""Stages used only by benchmarks/engine_overhead.py and benchmarks/stage_scaling.py (loaded through a
recipe's ``plugins:`` list).

``bench_source`` stamps each Blob's first 8 bytes with ``time.monotonic_ns()`` (one clock for every
process on the machine) just before building and publishing it; ``bench_sink`` records the one-way
latency at the entry of its handler and the arrival times for throughput. Both note their process's
CPU time (``time.process_time()``: every thread, zenoh's included) over the measured messages, so
the benchmark can compare CPU per message, which load from other programs disturbs much less than
wall-clock rates.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import ClassVar

import numpy as np

from engine.hookspecs import hookimpl
from engine.messages import Blob
from engine.stage import Stage, StageParams


def make_payload(base: bytes) -> bytes:
    """Timestamp + body, built the same way for vgr and for raw zenoh (one allocation, one copy of
    the body: allocator churn of 1.2 MB buffers otherwise dominates and varies from process to process)."""
    return b"".join((time.monotonic_ns().to_bytes(8, "little"), memoryview(base)[8:]))


def pace(slot: float, interval_s: float) -> float:
    """Sleep until the next send slot, *interval_s* after *slot* (``time.perf_counter()`` seconds),
    and return it; the same pacing for vgr and for raw zenoh."""
    slot += interval_s
    while (d := slot - time.perf_counter()) > 0:
        time.sleep(d)
    return slot


class BenchSource(Stage):
    """Publishes `count` Blobs of `size` bytes, paced by `interval_s` (0 = as fast as possible)."""

    type_name = "bench_source"
    role = "source"
    outputs: ClassVar = {"out": Blob}

    class Params(StageParams):
        size: int = 64
        count: int = 1000
        interval_s: float = 0.0
        warmup: int = 20
        output: str = ""  # JSON file for the sender's CPU time over the measured messages
        loan: bool = False  # build each payload in an array of ctx.loan (the port's pool: no copy to send)

    def run(self) -> None:
        p = self.params
        # parameters in locals, as the raw sender's loop has them (a pydantic attribute costs ~0.1 us)
        warmup, interval, ctx = p.warmup, p.interval_s, self.ctx
        base = bytes(max(p.size, 8))
        body = np.frombuffer(base, dtype=np.uint8)[8:]
        nxt = time.perf_counter()
        cpu0 = 0.0
        for i in range(p.count + warmup):
            if ctx.stopping:
                return
            if i == warmup:
                cpu0 = time.process_time()
            if interval:
                nxt = pace(nxt, interval)
            if p.loan:  # the same stamp and body as make_payload, written where the message will go
                stamp = time.monotonic_ns().to_bytes(8, "little")
                buf = ctx.loan("out", len(base))
                buf[:8] = np.frombuffer(stamp, dtype=np.uint8)
                buf[8:] = body
                ctx.publish("out", Blob(data=memoryview(buf)))
                del buf
                continue
            ctx.publish("out", Blob(data=make_payload(base)))
        if p.output:
            Path(p.output).write_text(json.dumps({"cpu_s": [cpu0, time.process_time()]}))


class BenchSink(Stage):
    """Records latency (ns) and arrival times of every Blob; writes them as JSON on finish."""

    type_name = "bench_sink"
    role = "sink"
    inputs: ClassVar = {"in": Blob}

    class Params(StageParams):
        output: str = "bench_sink.json"
        warmup: int = 20

    def setup(self) -> None:
        self.lat: list[int] = []
        self.arrivals: list[int] = []
        self.cpu = [0.0, 0.0]
        self.n = 0
        self.warmup = self.params.warmup  # (as the raw callback has it: a plain attribute)

    def on_message(self, port: str, msg: Blob) -> None:  # type: ignore[override]
        now = time.monotonic_ns()
        self.n += 1
        if self.n <= self.warmup:
            return
        self.lat.append(now - int.from_bytes(bytes(msg.data[:8]), "little"))
        self.arrivals.append(now)
        if len(self.lat) == 1:
            self.cpu[0] = time.process_time()

    def finish(self) -> None:  # right after the last message (its end of stream follows it)
        self.cpu[1] = time.process_time()
        Path(self.params.output).write_text(
            json.dumps({"lat_ns": self.lat, "arrivals_ns": self.arrivals, "cpu_s": self.cpu, "n": self.n})
        )


class BenchRelay(Stage):
    """Forwards each Blob as a new Blob with the same bytes (the message does not grow along a chain)."""

    type_name = "bench_relay"
    inputs: ClassVar = {"in": Blob}
    outputs: ClassVar = {"out": Blob}

    def on_message(self, port: str, msg: Blob) -> None:  # type: ignore[override]
        self.ctx.publish("out", Blob(data=msg.data))


class BenchTally(Stage):
    """Counts the Blobs it gets (no file: a fan-out has hundreds of these)."""

    type_name = "bench_tally"
    role = "sink"
    inputs: ClassVar = {"in": Blob}

    def setup(self) -> None:
        self.n = 0

    def on_message(self, port: str, msg: Blob) -> None:  # type: ignore[override]
        self.n += 1


@hookimpl
def vgr_stage_types() -> list[type]:
    return [BenchSource, BenchSink, BenchRelay, BenchTally]
