"""Stages used only by the engine tests, registered as a plugin module (recipe ``plugins:`` list).

``collector`` keeps what it received in ``COLLECTED[run_id][stage]`` (in-process tests) and can
also write it as JSON (subprocess tests).
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.hookspecs import hookimpl
from engine.messages import Blob, PointCloud, PoseStamped, Request
from engine.stage import ServiceSpec, Stage, StageParams

COLLECTED: dict[str, dict[str, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))


class Counter(Stage):
    """Emits Request messages with args {i: 0..n-1}; optionally forever until stopped."""

    type_name = "t_counter"
    role = "source"
    outputs: ClassVar = {"out": Request}

    class Params(StageParams):
        n: int = 10
        forever: bool = False
        rate_hz: float = 0.0
        in_setup: int = 0  # Requests published in setup() first (args.i -in_setup .. -1)

    def setup(self) -> None:
        for i in range(-self.params.in_setup, 0):  # type: ignore[attr-defined]
            self.ctx.publish("out", Request(command="count", args={"i": i}))

    def run(self) -> None:
        i = 0
        while (self.params.forever or i < self.params.n) and not self.ctx.stopping:  # type: ignore[attr-defined]
            self.ctx.publish("out", Request(command="count", args={"i": i}))
            i += 1
            if self.params.rate_hz and not self.ctx.sleep(1.0 / self.params.rate_hz):  # type: ignore[attr-defined]
                return


class Relay(Stage):
    """Forwards Requests, adding its name to args['path']; fails on args.i == fail_at."""

    type_name = "t_relay"
    inputs: ClassVar = {"in": Request}
    outputs: ClassVar = {"out": Request}

    class Params(StageParams):
        fail_at: int = -1

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        if msg.args.get("i") == self.params.fail_at:  # type: ignore[attr-defined]
            raise RuntimeError(f"planned failure at i={msg.args['i']}")
        args = dict(msg.args)
        args["path"] = [*args.get("path", []), self.ctx.name]
        self.ctx.publish("out", Request(command=msg.command, args=args))


class Merge(Stage):
    """Two inputs, one output: forwards everything, tagging the port it came in on."""

    type_name = "t_merge"
    inputs: ClassVar = {"a": Request, "b": Request}
    outputs: ClassVar = {"out": Request}

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        self.ctx.publish("out", Request(command=port, args=msg.args))


class Collector(Stage):
    """Keeps every received message (seq, command, args)."""

    type_name = "t_collector"
    role = "sink"
    inputs: ClassVar = {"in": Request}

    class Params(StageParams):
        output: str | None = None

    def setup(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        row = {"seq": msg.seq, "command": msg.command, "args": msg.args}
        self.rows.append(row)
        COLLECTED[self.ctx.run_id][self.ctx.name].append(row)

    def finish(self) -> None:
        if self.params.output:  # type: ignore[attr-defined]
            Path(self.params.output).write_text(json.dumps(self.rows))  # type: ignore[attr-defined]


class EchoService(Stage):
    """Service 'echo': replies with the request's args plus {'served_by': name}; 'boom' raises."""

    type_name = "t_echo"
    role = "sensor"
    services: ClassVar = {"echo": ServiceSpec(Request, Request, "echo the args back")}

    class Params(StageParams):
        delay_s: float = 0.0

    def on_request(self, service: str, request: Request) -> Request:  # type: ignore[override]
        if request.command == "boom":
            raise ValueError("boom requested")
        if self.params.delay_s:  # type: ignore[attr-defined]
            threading.Event().wait(self.params.delay_s)  # type: ignore[attr-defined]
        return Request(command="echo", args={**request.args, "served_by": self.ctx.name})


class Caller(Stage):
    """For each input, calls its 'svc' client and publishes the reply (or the error text)."""

    type_name = "t_caller"
    inputs: ClassVar = {"in": Request}
    outputs: ClassVar = {"out": Request}
    uses: ClassVar = {"svc": ServiceSpec(Request, Request)}

    class Params(StageParams):
        command: str = "echo"
        timeout_s: float = Field(5.0, gt=0)

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        from engine.stage import ServiceError

        try:
            reply = self.ctx.call(
                "svc",
                Request(command=self.params.command, args=msg.args),  # type: ignore[attr-defined]
                timeout_s=self.params.timeout_s,
            )  # type: ignore[attr-defined]
            self.ctx.publish("out", reply)
        except ServiceError as exc:
            self.ctx.publish("out", Request(command="error", args={"error": type(exc).__name__, "text": str(exc)}))


BUSY_RELEASE: dict[str, threading.Event] = defaultdict(threading.Event)  # run id -> ends t_busy's work
BUSY_STARTED: dict[str, threading.Event] = defaultdict(threading.Event)  # run id -> t_busy is at work


class Busy(Stage):
    """Service 'work': busy for ``busy_s`` without looking at ``ctx.stopping`` (a long matcher, a
    device call that blocks), unless the test sets ``BUSY_RELEASE[run_id]``."""

    type_name = "t_busy"
    role = "solver"
    services: ClassVar = {"work": ServiceSpec(Request, Request)}

    class Params(StageParams):
        busy_s: float = 30.0

    def on_request(self, service: str, request: Request) -> Request:  # type: ignore[override]
        BUSY_STARTED[self.ctx.run_id].set()
        BUSY_RELEASE[self.ctx.run_id].wait(self.params.busy_s)  # type: ignore[attr-defined]
        return Request(command="done")


HELPER_CALLS: dict[str, dict[str, Any]] = defaultdict(dict)  # run id -> what t_helper_caller's thread saw


class HelperCaller(Stage):
    """A source whose helper thread (not a thread of the engine's) calls 'svc' over and over until a
    call raises; ``HELPER_CALLS[run_id]`` counts the calls answered and names what ended the loop."""

    type_name = "t_helper_caller"
    role = "source"
    outputs: ClassVar = {"out": Request}
    uses: ClassVar = {"svc": ServiceSpec(Request, Request)}

    def _loop(self) -> None:
        seen = HELPER_CALLS[self.ctx.run_id]
        seen["answered"] = 0
        try:
            while True:
                self.ctx.call("svc", Request(command="echo"), timeout_s=30.0)
                seen["answered"] += 1
        except Exception as exc:
            seen["ended_by"] = type(exc).__name__

    def run(self) -> None:
        self.helper = threading.Thread(target=self._loop, name="helper-caller", daemon=True)
        self.helper.start()
        while self.ctx.sleep(0.05):
            pass


class RelayWithService(Relay):
    """A relay that also answers 'echo' (to build wait cycles in validation tests)."""

    type_name = "t_relay_service"
    services: ClassVar = {"echo": ServiceSpec(Request, Request)}

    def on_request(self, service: str, request: Request) -> Request:  # type: ignore[override]
        return request


class NeedsParam(Stage):
    """Has a required parameter (validation tests)."""

    type_name = "t_needs_param"
    role = "sink"
    inputs: ClassVar = {"in": Request}

    class Params(StageParams):
        factor: float


class BlobSink(Stage):
    """Counts Blob payload bytes."""

    type_name = "t_blob_sink"
    role = "sink"
    inputs: ClassVar = {"in": Blob}


def blob_bytes(i: int, size: int) -> bytes:
    """Payload *i* of t_blob_source: *size* bytes that differ from message to message."""
    return ((np.arange(size, dtype=np.int64) * 7 + i) % 251).astype(np.uint8).tobytes()


class BlobSource(Stage):
    """Publishes `n` Blobs of `size` bytes (:func:`blob_bytes`) and `n` clouds of `points` points."""

    type_name = "t_blob_source"
    role = "source"
    outputs: ClassVar = {"out": Blob, "cloud": PointCloud}

    class Params(StageParams):
        n: int = 3
        size: int = 1000
        points: int = 100

    def run(self) -> None:
        p = self.params
        for i in range(p.n):
            self.ctx.publish("out", Blob(data=blob_bytes(i, p.size)))
            pts = np.arange(3 * p.points, dtype=float).reshape(-1, 3) + i
            self.ctx.publish("cloud", PointCloud(points=pts, frame_id="grid"))


class DigestSink(Stage):
    """Writes, per message received, its port, sequence number, size and SHA-256 (JSON list)."""

    type_name = "t_digest_sink"
    role = "sink"
    inputs: ClassVar = {"blob": Blob, "cloud": PointCloud}

    class Params(StageParams):
        output: str = "digests.json"

    def setup(self) -> None:
        self.rows: list[list] = []

    def on_message(self, port: str, msg: Blob | PointCloud) -> None:  # type: ignore[override]
        data = bytes(msg.data) if isinstance(msg, Blob) else np.ascontiguousarray(msg.points).tobytes()
        self.rows.append([port, msg.seq, len(data), hashlib.sha256(data).hexdigest()])

    def finish(self) -> None:
        Path(self.params.output).write_text(json.dumps(self.rows))


@hookimpl
def vgr_stage_types() -> list[type]:
    return [
        BlobSource,
        DigestSink,
        Counter,
        Relay,
        Merge,
        Collector,
        EchoService,
        Caller,
        BlobSink,
        NeedsParam,
        RelayWithService,
        NoisyCloud,
        ThreadedCentroid,
        Busy,
        HelperCaller,
    ]


class NoisyCloud(Stage):
    """For each Request, a PointCloud of args.i + n points drawn from the stage's seeded generator."""

    type_name = "t_noisy_cloud"
    role = "solver"
    inputs: ClassVar = {"in": Request}
    outputs: ClassVar = {"cloud": PointCloud}

    class Params(StageParams):
        n: int = 50
        scale: float = 1.0

    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        k = self.params.n + int(msg.args.get("i", 0))  # type: ignore[attr-defined]
        pts = self.ctx.rng.normal(scale=self.params.scale, size=(k, 3))  # type: ignore[attr-defined]
        self.ctx.publish("cloud", PointCloud(points=pts, frame_id="noise"))


class ThreadedCentroid(Stage):
    """Centroid of each cloud computed by 4 worker threads over chunks, combined in chunk order."""

    type_name = "t_threaded_centroid"
    role = "solver"
    inputs: ClassVar = {"cloud": PointCloud}
    outputs: ClassVar = {"centroid": PoseStamped}

    def setup(self) -> None:
        self.pool = ThreadPoolExecutor(max_workers=4)

    def on_message(self, port: str, msg: PointCloud) -> None:  # type: ignore[override]
        chunks = np.array_split(np.asarray(msg.points, dtype=float), 4)
        sums = list(self.pool.map(lambda c: c.sum(axis=0), chunks))  # results come back in chunk order
        T = np.eye(4)
        T[:3, 3] = np.sum(sums, axis=0) / max(1, len(msg.points))
        self.ctx.publish("centroid", PoseStamped(T=T, frame_id=msg.frame_id))

    def teardown(self) -> None:
        self.pool.shutdown()
