"""One stage at run time: its context (publish, call, events), its locks and counters, its threads.

The runner (engine.runner) creates a :class:`StageRuntime` per stage of this process. Each input
port and each service gets a pump thread that blocks on the port's zenoh FIFO channel and hands
messages to the stage under the stage's lock, so the stage's handlers never run concurrently and
each port's messages arrive in publication order. A failure inside a handler becomes an ``error``
Event with the traceback, never a silent death.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
import zlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from engine import codec
from engine.bus import Inbox, data_key, service_key
from engine.codec import CodecError, Envelope, Kind
from engine.graph import StageNode
from engine.messages import Event, Message
from engine.stage import EVENTS_PORT, ServiceError, ServiceTimeoutError, Stage, StageContext

if TYPE_CHECKING:
    import zenoh

    from engine.runner import Runner

log = logging.getLogger("vgr.runtime")
INBOX_WARN = 1000  # first backlog (messages) of a cross-process input that raises a warning


@dataclass
class StageStats:
    """Per-stage counters reported at the end of a run (and live by the progress display)."""

    name: str
    type_name: str
    process: str
    role: str
    received: dict[str, int] = field(default_factory=dict)
    published: dict[str, int] = field(default_factory=dict)
    requests_served: int = 0
    calls_made: int = 0
    errors: int = 0
    busy_s: float = 0.0
    state: str = "pending"  # pending | running | finished | failed | stopped
    error: str = ""

    @property
    def messages_in(self) -> int:
        return sum(self.received.values())

    @property
    def messages_out(self) -> int:
        return sum(v for k, v in self.published.items() if k != EVENTS_PORT)


class StageRuntime(StageContext):
    """The engine side of one stage in this process (implements StageContext)."""

    def __init__(self, runner: Runner, node: StageNode) -> None:
        self.runner = runner
        self.node = node
        self.name = node.name
        self.run_id = runner.run_id
        self.seed = runner.seed
        self.rng = np.random.default_rng([runner.seed & 0xFFFFFFFF, zlib.crc32(node.name.encode())])
        self.clock = runner.clock
        self.log = logging.getLogger(f"vgr.stage.{node.name}")
        self.lock = threading.RLock()  # serialises the stage's handlers
        self._pub_lock = threading.Lock()  # keeps seq order == wire order per port
        self.stats = StageStats(
            node.name,
            node.cls.type_name,
            node.spec.process,
            node.cls.role,
            received={p: 0 for p in node.cls.inputs},
            published={p: 0 for p in node.cls.all_outputs()},
        )
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._seq: dict[str, int] = {p: 0 for p in node.cls.all_outputs()}
        self._closed_ports: set[str] = set()
        self._last_in_seq: dict[str, int] = {}
        self.pending_inputs: set[str] = set(node.cls.inputs)
        self.failed = False
        self.data_done = threading.Event()
        self.threads: list[threading.Thread] = []
        self.stage: Stage | None = None
        self.channels: dict[str, Any] = {}  # input port -> subscriber
        self.queryables: dict[str, Any] = {}  # service -> queryable
        self.clients = {e.client_name: e for e in runner.graph.service_edges if e.client == node.name}

    # -- StageContext ------------------------------------------------------------------------
    @property
    def stopping(self) -> bool:
        return self.runner.stop_event.is_set()

    def sleep(self, seconds: float) -> bool:
        return self.clock.sleep(seconds, self.runner.stop_event)

    def publish(self, port: str, msg: Message) -> None:
        outs = self.node.cls.all_outputs()
        if port not in outs:
            raise ValueError(f"stage {self.name!r} has no output port {port!r} (outputs: {', '.join(outs)})")
        if not isinstance(msg, outs[port]):
            raise TypeError(f"stage {self.name!r}: port {port!r} carries {outs[port].TYPE}, got {type(msg).__name__}")
        with self._pub_lock:
            if port in self._closed_ports:
                raise RuntimeError(f"stage {self.name!r}: port {port!r} has already ended")
            self._seq[port] += 1
            msg.seq = self._seq[port]
            if not msg.stamp_ns:
                msg.stamp_ns = self.clock.now_ns()
            payload, att = codec.encode(msg)
            self._publishers[port].put(payload, attachment=att)
            self.stats.published[port] += 1
        for obs in self.runner.observers:
            obs.on_publish(self.name, port, payload, att, msg)

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        edge = self.clients.get(client)
        if edge is None:
            raise ServiceError(f"stage {self.name!r} has no service client {client!r} wired in the recipe")
        spec = self.node.cls.uses[client]
        if not isinstance(request, spec.request):
            raise TypeError(f"client {client!r} sends {spec.request.TYPE}, got {type(request).__name__}")
        if not request.stamp_ns:
            request.stamp_ns = self.clock.now_ns()
        payload, att = codec.encode(request)
        key = service_key(self.run_id, edge.provider, edge.service)
        self.stats.calls_made += 1
        reply_payload, reply_att, error = b"", b"", ""
        try:
            reply_payload, reply_att = self.runner.bus.request(key, payload, att, timeout_s)
            reply = codec.decode(reply_payload, codec.decode_envelope(reply_att))
        except TimeoutError as exc:
            error = str(exc)
            raise ServiceTimeoutError(f"{self.name} -> {edge.provider}.{edge.service}: {exc}") from None
        except (LookupError, RuntimeError, CodecError) as exc:
            error = str(exc)
            raise ServiceError(f"{self.name} -> {edge.provider}.{edge.service}: {exc}") from None
        finally:
            for obs in self.runner.observers:
                obs.on_service(self.name, client, edge, payload, att, reply_payload, reply_att, error)
        if not isinstance(reply, spec.reply):
            raise ServiceError(
                f"{edge.provider}.{edge.service} replied {type(reply).__name__}, expected {spec.reply.TYPE}"
            )
        return reply

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        tb = details.pop("traceback", "")
        ev = Event(level=level, code=code, stage=self.name, message=message, traceback=tb, details=details)
        self.runner.note_event(ev)
        if self.node.cls.all_outputs() and EVENTS_PORT in self._publishers and EVENTS_PORT not in self._closed_ports:
            self.publish(EVENTS_PORT, ev)

    # -- wiring ------------------------------------------------------------------------------
    def declare(self) -> None:
        bus = self.runner.bus
        for port in self.node.cls.all_outputs():
            self._publishers[port] = bus.publisher(data_key(self.run_id, self.name, port))
        for edge in self.runner.graph.inputs_of(self.name):
            key = data_key(self.run_id, edge.src, edge.src_port)
            local = self.runner.graph.nodes[edge.src].spec.process == self.node.spec.process
            self.channels[edge.dst_port] = bus.channel(key) if local else bus.inbox(key)
        for svc in self.node.cls.services:
            self.queryables[svc] = bus.queryable(service_key(self.run_id, self.name, svc))

    @property
    def driven(self) -> bool:
        return self.name in self.runner.driven

    def start_threads(self) -> None:
        for port, sub in self.channels.items():
            self._spawn(f"{self.name}.{port}", self._input_pump, port, sub)
        for svc, q in self.queryables.items():
            self._spawn(f"{self.name}.srv.{svc}", self._service_pump, svc, q)
        if self.node.cls.is_source():
            self._spawn(f"{self.name}.run", self._source_main)

    def _spawn(self, name: str, target: Any, *args: Any) -> None:
        t = threading.Thread(target=target, args=args, name=f"vgr:{name}", daemon=True)
        self.threads.append(t)
        t.start()

    # -- threads -----------------------------------------------------------------------------
    def _source_main(self) -> None:
        assert self.stage is not None
        try:
            self.stage.run()
        except Exception as exc:
            self.fail(exc, "run")
        finally:
            if not self.stopping:
                self.close_outputs()
            self._mark_data_done()

    def _input_pump(self, port: str, sub: Any) -> None:
        """Read one input port until end of stream; once the run stops, drain without delivering
        (so producers never block on a full channel) until the local STOP marker arrives."""
        stop = self.runner.stop_event
        backlog_warned = INBOX_WARN
        while True:
            sample = sub.recv()
            if isinstance(sub, Inbox) and len(sub) >= backlog_warned:
                self.event(
                    "warning",
                    "input_backlog",
                    f"input {port!r} has {len(sub)} messages waiting: this stage "
                    "is slower than its producer in another process",
                    backlog=len(sub),
                )
                backlog_warned *= 4
            att = sample.attachment
            try:
                env = codec.decode_envelope(att.to_bytes() if att is not None else b"")
            except CodecError as exc:
                if not stop.is_set():
                    self.event("warning", "foreign_message", f"ignored a message on input {port!r}: {exc}")
                continue
            if env.kind == Kind.STOP:
                return
            if stop.is_set() or self.failed:
                continue
            if env.kind == Kind.EOS:
                self.input_ended(port)
                return
            self._check_seq(port, env)
            try:
                msg = codec.decode(sample.payload.to_bytes(), env)
            except CodecError as exc:
                self.fail(exc, f"decode {port}")
                continue
            self.deliver(port, msg, env)

    def _check_seq(self, port: str, env: Envelope) -> None:
        last = self._last_in_seq.get(port, 0)
        if env.seq != last + 1:
            self.event(
                "warning",
                "sequence_gap",
                f"input {port!r}: expected seq {last + 1}, got {env.seq}",
                expected=last + 1,
                got=env.seq,
            )
        self._last_in_seq[port] = env.seq

    def deliver(self, port: str, msg: Message, env: Envelope) -> None:
        assert self.stage is not None
        with self.lock:
            if self.failed:
                return
            self.stats.received[port] += 1
            for obs in self.runner.observers:
                obs.on_deliver(self.name, port, env)
            t0 = time.perf_counter()
            try:
                self.stage.on_message(port, msg)
            except Exception as exc:
                self.fail(exc, f"on_message({port!r})")
            finally:
                self.stats.busy_s += time.perf_counter() - t0

    def _service_pump(self, svc: str, queryable: Any) -> None:
        stop = self.runner.stop_event
        spec = self.node.cls.services[svc]
        while True:
            query = queryable.recv()
            with query:
                if stop.is_set():
                    return
                att = query.attachment
                try:
                    env = codec.decode_envelope(att.to_bytes() if att is not None else b"")
                    if env.kind == Kind.STOP:
                        return
                    payload = query.payload.to_bytes() if query.payload is not None else b""
                    request = codec.decode(payload, env)
                    if not isinstance(request, spec.request):
                        raise CodecError(f"service {svc!r} takes {spec.request.TYPE}, got {type(request).__name__}")
                except CodecError as exc:
                    query.reply_err(f"bad request to {self.name}.{svc}: {exc}")
                    continue
                reply_bytes: tuple[bytes, bytes] | None = None
                error = ""
                with self.lock:
                    t0 = time.perf_counter()
                    try:
                        assert self.stage is not None
                        reply = self.stage.on_request(svc, request)
                        if not isinstance(reply, spec.reply):
                            raise TypeError(f"service {svc!r} must reply {spec.reply.TYPE}, got {type(reply).__name__}")
                        if not reply.stamp_ns:
                            reply.stamp_ns = self.clock.now_ns()
                        reply_bytes = codec.encode(reply)
                    except Exception as exc:  # the caller gets the error; the stage keeps serving
                        error = f"{type(exc).__name__}: {exc}"
                        self.stats.errors += 1
                        self.event("error", "service_exception", f"{svc}: {error}", traceback=traceback.format_exc())
                    finally:
                        self.stats.busy_s += time.perf_counter() - t0
                        self.stats.requests_served += 1
                if reply_bytes is not None:
                    query.reply(query.key_expr, reply_bytes[0], attachment=reply_bytes[1])
                else:
                    query.reply_err(f"{self.name}.{svc} failed: {error}")

    # -- state changes -----------------------------------------------------------------------
    def input_ended(self, port: str) -> None:
        with self.lock:
            self.pending_inputs.discard(port)
            if self.pending_inputs or self.data_done.is_set():
                return
            if not self.failed and self.stage is not None:
                try:
                    self.stage.finish()
                except Exception as exc:
                    self.fail(exc, "finish")
        self.close_outputs()
        self._mark_data_done()

    def _mark_data_done(self) -> None:
        if self.stats.state == "running":
            self.stats.state = "finished"
        self.data_done.set()
        self.runner.stage_done(self)

    def close_outputs(self) -> None:
        """Send end-of-stream on every data output (not ``events``, which closes at teardown)."""
        for port in self.node.cls.outputs:
            self._close_port(port)

    def _close_port(self, port: str) -> None:
        with self._pub_lock:
            if port in self._closed_ports or port not in self._publishers:
                return
            self._closed_ports.add(port)
            env = codec.encode_envelope(Envelope(Kind.EOS, self._seq[port] + 1, self.clock.now_ns(), ""))
            self._publishers[port].put(b"", attachment=env)

    def fail(self, exc: BaseException, where: str) -> None:
        """Record a stage failure as an error Event with traceback and tell the runner."""
        self.failed = True
        self.stats.errors += 1
        self.stats.state = "failed"
        self.stats.error = f"{type(exc).__name__} in {where}: {exc}"
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.log.error("stage %s failed in %s: %s", self.name, where, exc)
        try:
            self.event("error", "stage_exception", self.stats.error, traceback=tb, where=where)
        except Exception:  # publishing the event must not hide the original failure
            log.exception("could not publish the error event of %s", self.name)
        self.runner.stage_failed(self)

    def teardown(self) -> None:
        if self.stage is not None:
            try:
                self.stage.teardown()
            except Exception as exc:
                self.stats.errors += 1
                self.stats.error = self.stats.error or f"teardown: {exc}"
                self.runner.note_event(
                    Event(
                        level="error",
                        code="teardown_exception",
                        stage=self.name,
                        message=str(exc),
                        traceback=traceback.format_exc(),
                    )
                )
        self._close_port(EVENTS_PORT)
