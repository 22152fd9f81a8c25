"""One stage at run time: its context (publish, call, events), its locks and counters, its threads.

The runner (engine.run.runner) creates a :class:`StageRuntime` per stage of this process; the runtime
sees it only as its :class:`~engine.run.stage_host.StageHost`.

Data path of ``publish(port, msg)``:

* consumers in this process get the message object itself, its arrays frozen read-only through their
  :class:`~engine.run.inbox.PortInbox` (handled inline on the publisher's thread when the consumer is
  idle, else by the consumer's pump thread; see engine.run.inbox);
* when anything outside the process may listen — a stage of another process, an external zenoh
  subscriber (a robot controller, a viewer), or a run observer such as the recorder — the message is
  encoded once (engine.messages.codec; the envelope packed by the port's :class:`~engine.messages.codec.DataFormat` in
  one struct call) and goes where the port (:class:`~engine.run.output_port.OutputPort`) says: to
  stages of other processes through its :class:`~engine.transport.wire.WireSender` (put at once when the
  port is idle, batched while it bursts), to an external subscriber on ``vgr/<run>/<stage>/<port>``
  only while one listens there.

An input fed by a stage of another process is a :class:`~engine.run.remote_input.RemoteInput`: a zenoh
subscriber whose messages are decoded (a large one of this host as a read-only view of the
producer's shared memory) and handed to :meth:`StageRuntime._deliverer`'s function for the port, as
local inputs do: on zenoh's receive thread for a stage that calls no service and whose outputs stay
in this process (engine.run.remote_input.receive_thread_safe), else by the port's pump thread. A service the stage
serves is a :class:`~engine.run.service_port.ServicePort`: its pump thread takes the queries, refuses
what must not be served and replies; the runtime's serve function (``_serve``) runs the stage's
handler under the stage's lock.

Per message the hot paths do only what the message needs: everything fixed for a port (its
publisher, envelope format, message class, consumers' offer functions, the deliver function with
its counters) is bound once when the port is declared. Measured with callgrind on 64 B Blobs going
to another process (instructions per message): building and publishing one 69 k -> 55 k, receiving,
decoding and handing one to the benchmark's sink 58 k -> 38 k, where raw zenoh needs 12 k to put
and 4 k to take the bytes out of the channel. What remains is mostly the typed message itself
(dataclass construction; protobuf encode ~18 k and decode ~16 k through upb's Python API).

Handlers of one stage never run concurrently (one re-entrant lock per stage) and each input port's
messages arrive in publication order. A failure inside a handler becomes an ``error`` Event with
its traceback, never a silent death.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from time import perf_counter
from typing import Any

import numpy as np

from engine.graph import StageNode
from engine.messages import Event, Message, canonical, codec, detach, freeze_arrays
from engine.messages.codec import CodecError, Envelope, Kind
from engine.run.inbox import END, STOP, PortInbox
from engine.run.output_port import OutputPort
from engine.run.remote_input import RemoteInput, receive_thread_safe
from engine.run.service_call import CUT_SHORT, exchange
from engine.run.service_port import ServicePort
from engine.run.stage_host import StageHost
from engine.stage import EVENTS_PORT, RunStoppingError, ServiceError, ServiceTimeoutError, Stage, StageContext
from engine.transport.bus import RequestCancelled, service_key, wire_key
from engine.transport.peers import ForgedReply

_UINT8 = np.dtype(np.uint8)
log = logging.getLogger("vgr.runtime")
LOCAL_QUEUE_DEPTH = 64  # messages a local producer may run ahead of its consumer
_EOS = Kind.EOS  # (an Enum attribute lookup costs more than the test)
_encode_parts = codec.encode_parts


class _Causal(threading.local):
    """Per thread: the stamp of the input being handled (0 outside a handler)."""

    stamp = 0


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


class _InlineDepth(threading.local):
    depth = 0  # handlers of this thread running inline, one inside the other (a chain of stages)


_INLINE = _InlineDepth()
# A chain of idle stages would otherwise run each handler inside its producer's, one stack level
# set per stage: a chain of 200 stages overflowed Python's recursion limit. Past this depth the
# message goes to the consumer's own pump thread, as it does when the consumer is busy.
MAX_INLINE_DEPTH = 16


class StageRuntime(StageContext):
    """The engine side of one stage in this process (implements StageContext for the stage and
    PortOwner for its ports), run by *host*."""

    def __init__(self, host: StageHost, node: StageNode) -> None:
        path = host.graph.loaded.path
        recipe_dir = path.resolve().parent if path is not None and path.is_file() else None
        log = logging.getLogger(f"vgr.stage.{node.name}")
        super().__init__(node.name, host.run_id, host.seed, host.clock, log, recipe_dir)
        self.run_dir = host.run_dir
        self.host = host
        self.node = node
        self.lock = threading.RLock()  # serialises the stage's handlers
        self.serving = ""  # the service whose request the stage is handling now ("": none)
        self.inline = node.spec.dispatch == "auto"
        self.stats = StageStats(
            node.name,
            node.cls.type_name,
            node.spec.process,
            node.cls.role,
            received={p: 0 for p in node.cls.inputs},
            published={p: 0 for p in node.cls.all_outputs()},
        )
        self.outputs: dict[str, OutputPort] = {}
        self.inboxes: dict[str, PortInbox | RemoteInput] = {}
        self.service_ports: dict[str, ServicePort] = {}  # service -> its queryable and pump (engine.run.service_port)
        self._deliver: dict[str, Any] = {}  # input port -> its deliver function (see _deliverer)
        self.pending_inputs: set[str] = set(node.cls.inputs)
        self.failed = False
        self.data_done = threading.Event()
        self.threads: list[threading.Thread] = []
        self._pumped: set[str] = set()  # local inputs whose pump thread is started (see start_threads)
        self._spawn_lock = threading.Lock()
        self.threads_ended_at = 0.0  # time.monotonic() when the last of its threads ended
        self.stage: Stage | None = None
        self.clients = {e.client_name: e for e in host.graph.service_edges if e.client == node.name}
        self._causal = _Causal()  # stamp of the input being handled on this thread
        self._stop_event = host.stop_event
        self._observers = host.observers  # the host's list (fixed before the run starts)
        self._call_seq: dict[str, int] = {}  # requests sent per service client

    # -- StageContext ------------------------------------------------------------------------
    @property
    def stopping(self) -> bool:
        return self._stop_event.is_set()

    def sleep(self, seconds: float) -> bool:
        return self.clock.sleep(seconds, self._stop_event)

    def loan(self, port: str, shape: int | tuple[int, ...], dtype: Any = np.uint8) -> np.ndarray:
        out = self.outputs.get(port)
        if out is None:
            raise ValueError(f"stage {self.name!r} has no output port {port!r}")
        dt = np.dtype(dtype)
        dims = (shape,) if isinstance(shape, int) else tuple(shape)
        if out.views is not None:  # consumers in other processes: maybe on this host
            buf = out.views.loan(math.prod(dims) * dt.itemsize)
            if buf is not None:  # (a byte buffer as it is: no view to make)
                return buf if dt == _UINT8 and len(dims) == 1 else buf.view(dt).reshape(dims)
        return np.empty(dims, dtype=dt)

    def publish(self, port: str, msg: Message) -> None:
        out = self.outputs.get(port)
        if out is None:
            outs = ", ".join(self.node.cls.all_outputs())
            raise ValueError(f"stage {self.name!r} has no output port {port!r} (outputs: {outs})")
        if not isinstance(msg, out.type):
            raise TypeError(f"stage {self.name!r}: port {port!r} carries {out.type.TYPE}, got {type(msg).__name__}")
        stamp = msg.stamp_ns or self._causal.stamp or self.clock.now_ns()
        msg = detach(msg)  # a message published before is copied (what its consumers hold stays as is)
        if msg.stamp_ns != stamp:
            msg.stamp_ns = stamp
        exact = msg.WIRE_EXACT
        if not exact:
            freeze_arrays(msg)
            msg = canonical(msg)  # what a remote consumer and a replay will see (stamp included)
        with out.lock:
            if out.closed:
                raise RuntimeError(f"stage {self.name!r}: port {port!r} has already ended")
            seq = out.seq = out.seq + 1
            msg.seq = seq
            if out.needs_bytes:
                fmt = out.format
                att = fmt.pack(fmt.head, seq, msg.stamp_ns, fmt.name)
                head, bulk = _encode_parts(msg)
                shown = None  # the bytes observers and foreign subscribers get, when payload is a view
                if bulk is None:
                    payload = head
                elif out.wrap_parts is not None:
                    payload = out.wrap_parts(head, bulk)  # into shared memory, not joined first (engine.transport.shm)
                elif out.views is not None and (placed := out.views.place(head, bulk, hold=True)) is not None:
                    payload, shown = placed, placed.view  # (recorded: the recorder is handed the block's bytes)
                else:
                    payload = b"".join((head, bulk))
                for obs in self._observers:
                    obs.on_publish(self.name, port, payload if shown is None else shown, att, msg)
                if out.external:
                    out.put(payload if shown is None else bytes(shown), attachment=att)
                if out.send is not None:
                    out.send(payload, att)
            if exact:  # frozen before any consumer here holds it, after the bytes are on their way
                freeze_arrays(msg)
            self.stats.published[port] += 1
            for offer in out.local:
                offer(msg)

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        edge = self.clients.get(client)
        if edge is None:
            raise ServiceError(f"stage {self.name!r} has no service client {client!r} wired in the recipe")
        if self._stop_event.is_set():  # Ctrl-C, a failure or a stop request: nothing new goes out (no motion)
            raise RunStoppingError(f"{self.name} -> {edge.provider}.{edge.service}: not sent, the run is stopping")
        spec = self.node.cls.uses[client]
        if not isinstance(request, spec.request):
            raise TypeError(f"client {client!r} sends {spec.request.TYPE}, got {type(request).__name__}")
        if not request.stamp_ns:
            request.stamp_ns = self._causal.stamp or self.clock.now_ns()
        self._call_seq[client] = request.seq = self._call_seq.get(client, 0) + 1
        self.stats.calls_made += 1
        where = f"{self.name} -> {edge.provider}.{edge.service}"
        try:
            reply = exchange(self.host, self.name, edge, request, timeout_s, self._observers)
        except ForgedReply as exc:  # nothing is taken from this request: no result, no motion
            self.event(
                "alarm", "forged_reply", str(exc), service=f"{edge.provider}.{edge.service}", repliers=exc.repliers
            )
            raise ServiceError(str(exc)) from None
        except RequestCancelled:  # the stop came first: no reply is awaited (nor sent, if it was not yet)
            raise RunStoppingError(f"{where}: {CUT_SHORT}") from None
        except (TimeoutError, LookupError, RuntimeError, CodecError) as exc:
            if self._stop_event.is_set():  # a call that failed while the run stops: the stop's doing
                raise RunStoppingError(f"{where}: {exc} (the run is stopping)") from None
            if isinstance(exc, TimeoutError):
                raise ServiceTimeoutError(f"{where}: {exc}") from None
            raise ServiceError(f"{where}: {exc}") from None
        if not isinstance(reply, spec.reply):
            raise ServiceError(
                f"{edge.provider}.{edge.service} replied {type(reply).__name__}, expected {spec.reply.TYPE}"
            )
        return reply

    def has_client(self, client: str) -> bool:
        return client in self.clients

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        tb = details.pop("traceback", "")
        details = self.files_in_run(details)
        ev = Event(level=level, code=code, stage=self.name, message=message, traceback=tb, details=details)
        self.host.note_event(ev)
        out = self.outputs.get(EVENTS_PORT)
        if out is not None and not out.closed:
            self.publish(EVENTS_PORT, ev)

    # -- wiring ------------------------------------------------------------------------------
    def declare_outputs(self) -> None:
        for port in self.node.cls.all_outputs():
            self.outputs[port] = OutputPort(self, port)
        for svc in self.node.cls.services:
            queryable = self.host.bus.queryable(service_key(self.run_id, self.name, svc))
            self.service_ports[svc] = ServicePort(self, svc, queryable, self._serve)

    def declare_inputs(self, local: Mapping[str, StageRuntime]) -> None:
        """Create the input queues; producers among the *local* stages (this process's, their outputs
        declared) are linked to them, remote ones subscribed."""
        for edge in self.host.graph.inputs_of(self.name):
            producer = local.get(edge.src)
            deliver = self._deliver[edge.dst_port] = self._deliverer(edge.dst_port)
            if producer is not None:  # same process
                self.inboxes[edge.dst_port] = PortInbox(edge.dst_port, LOCAL_QUEUE_DEPTH)
                producer.outputs[edge.src_port].local.append(self._offerer(edge.dst_port))
            else:
                key = wire_key(self.run_id, edge.src, edge.src_port)
                # handed over on zenoh's receive thread when nothing of this stage can wait there
                rx = receive_thread_safe(self.host.graph, self.name)
                self.inboxes[edge.dst_port] = RemoteInput(self, edge.dst_port, key, deliver, on_receive_thread=rx)

    def start_threads(self) -> None:
        """Start the threads that read inputs and serve requests (not a source's run()). A local
        input gets its pump thread only once a message has to wait for it (:meth:`_ensure_pump`):
        while the stage is idle its producers hand messages over on their own threads, so a stage
        fed only that way (a fan-out's consumers) costs no thread at all."""
        for port, box in self.inboxes.items():
            if isinstance(box, PortInbox):
                if len(box):  # published during set-up: waiting already
                    self._ensure_pump(port, box)
            else:
                self._spawn(f"{self.name}.{port}", box.pump)
        for svc, service in self.service_ports.items():
            self._spawn(f"{self.name}.srv.{svc}", service.pump)

    def _ensure_pump(self, port: str, box: PortInbox) -> None:
        """Start *port*'s pump thread if it has none yet (before a message is queued for it)."""
        if port in self._pumped:
            return
        with self._spawn_lock:
            if port not in self._pumped:
                self._pumped.add(port)
                self._spawn(f"{self.name}.{port}", self._input_pump, port, box)

    def start_source(self) -> None:
        if self.node.cls.is_source():
            self._spawn(f"{self.name}.run", self._source_main)

    def spawn_thread(self, name: str, target: Any, *args: Any) -> None:
        """Run *target(*args)* on a thread of this stage (joined when the run ends)."""
        self._spawn(name, target, *args)

    def _spawn(self, name: str, target: Any, *args: Any) -> None:
        def main() -> None:
            try:
                target(*args)
            finally:  # (how long a stop took to end this stage: see Runner._join_stages)
                self.threads_ended_at = time.monotonic()

        t = threading.Thread(target=main, name=f"vgr:{name}", daemon=True)
        self.threads.append(t)
        t.start()

    # -- delivery ----------------------------------------------------------------------------
    def _offerer(self, port: str) -> Any:
        """The function a local producer calls to hand over a message of input *port* (or END).

        Before every stage is set up, the message waits in the port's queue. Then, if the stage is
        idle (``dispatch: auto``, nothing queued or in flight, stage lock free), the producer's
        thread runs the handler at once; otherwise the message is queued for the port's pump."""
        box = self.inboxes[port]
        assert isinstance(box, PortInbox)
        deliver, host, inline = self._deliver[port], self.host, self.inline
        claim, done, put = box.claim_idle, box.release, box.put
        acquire, release = self.lock.acquire, self.lock.release

        pumped, ensure_pump = self._pumped, self._ensure_pump

        def offer(msg: Message | object) -> None:
            if not host.started:  # published during setup(): delivered once every stage is set up
                put(msg, block=False)
                return
            if inline and _INLINE.depth < MAX_INLINE_DEPTH and claim():
                if acquire(False):
                    _INLINE.depth += 1
                    try:
                        deliver(msg)
                    finally:
                        _INLINE.depth -= 1
                        release()
                        done()
                    return
                done()
            if port not in pumped:  # the first message that must wait: its pump starts now
                ensure_pump(port, box)
            put(msg)

        return offer

    def _input_pump(self, port: str, box: PortInbox) -> None:
        """Thread of a local input: handles what the producer queued while this stage was busy."""
        deliver, lock = self._deliver[port], self.lock
        while True:
            msg = box.get()
            try:
                if msg is STOP:
                    return
                with lock:
                    deliver(msg)
                if msg is END:
                    return
            finally:
                box.release()

    def _deliverer(self, port: str) -> Any:
        """The function delivering input *port*'s messages (each ``seq`` is its envelope's) and its
        END to the stage; its caller holds the stage lock. One closure per port: what it needs per
        message is bound once."""
        stop_is_set, observers, causal, stats, name = (
            self._stop_event.is_set,
            self._observers,
            self._causal,
            self.stats,
            self.name,
        )
        received = stats.received
        last = 0  # seq of the port's last message

        def deliver(msg: Any) -> None:
            nonlocal last
            if stop_is_set() or self.failed:
                return
            if msg is END:
                self._input_ended(port)
                return
            seq = msg.seq
            if seq != last + 1:
                self.event(
                    "warning",
                    "sequence_gap",
                    f"input {port!r}: expected seq {last + 1}, got {seq}",
                    expected=last + 1,
                    got=seq,
                )
            last = seq
            received[port] += 1
            if observers:
                env = codec.data_envelope(seq, msg.stamp_ns, msg.TYPE)
                for obs in observers:
                    obs.on_deliver(name, port, env)
            t0 = perf_counter()
            causal.stamp = msg.stamp_ns
            try:
                self.stage.on_message(port, msg)  # type: ignore[union-attr]
            except Exception as exc:
                self.fail(exc, f"on_message({port!r})")
            finally:
                causal.stamp = 0
                stats.busy_s += perf_counter() - t0

        return deliver

    def _input_ended(self, port: str) -> None:
        self.pending_inputs.discard(port)
        self.inboxes[port].close()  # its pump exits (the end may have been handled inline)
        if self.pending_inputs or self.data_done.is_set():
            self.host.input_ended(self.name)
            return
        if not self.failed and self.stage is not None:
            for obs in self._observers:
                obs.on_stage_finish(self.name)
            try:
                self.stage.finish()
            except Exception as exc:
                self.fail(exc, "finish")
        self.close_outputs()
        self._mark_data_done()

    # -- sources and served requests ---------------------------------------------------------
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

    def _serve(self, svc: str, reply_type: type[Message], request: Message) -> tuple[tuple[bytes, bytes] | None, str]:
        """Hand *request* to the stage's service *svc* (for its ServicePort): the encoded reply, or
        None and the error, which the stage survives (it goes on serving)."""
        with self.lock:
            t0 = time.perf_counter()
            self.serving = svc
            self._causal.stamp = request.stamp_ns
            try:
                assert self.stage is not None
                reply = self.stage.on_request(svc, request)
                if not isinstance(reply, reply_type):
                    raise TypeError(f"service {svc!r} must reply {reply_type.TYPE}, got {type(reply).__name__}")
                if not reply.stamp_ns:
                    reply.stamp_ns = request.stamp_ns or self.clock.now_ns()
                return codec.encode(reply), ""
            except Exception as exc:  # the caller gets the error; the stage keeps serving
                error = f"{type(exc).__name__}: {exc}"
                self.stats.errors += 1
                self.event("error", "service_exception", f"{svc}: {error}", traceback=traceback.format_exc())
                return None, error
            finally:
                self.serving = ""
                self._causal.stamp = 0
                self.stats.busy_s += time.perf_counter() - t0
                self.stats.requests_served += 1

    # -- state changes -----------------------------------------------------------------------
    def _mark_data_done(self) -> None:
        if self.stats.state == "running" and not self.stopping:  # (ended by a stop: the runner says "stopped")
            self.stats.state = "finished"
        self.data_done.set()
        self.host.stage_done(self.name)

    def close_outputs(self) -> None:
        """Send end-of-stream on every data output (not ``events``, which closes at teardown)."""
        for port in self.node.cls.outputs:
            self._close_port(port)

    def _close_port(self, port: str) -> None:
        out = self.outputs.get(port)
        if out is None:
            return
        with out.lock:
            if out.closed:
                return
            out.closed = True
            eos = codec.encode_envelope(Envelope(_EOS, out.seq + 1, self.clock.now_ns(), ""))
            if out.external:
                out.publisher.put(b"", attachment=eos)
            if out.wire is not None:
                out.wire.send(b"", eos)
                out.wire.close()  # after what is queued, then the sender thread ends
            for offer in out.local:
                offer(END)

    def fail(self, exc: BaseException, where: str) -> None:
        """Record a stage failure as an error Event with traceback and tell the host (a request the
        stop refused is the stop's doing: noted as info, not a failure)."""
        if isinstance(exc, RunStoppingError) and self._stop_event.is_set():
            self.log.info("stage %s ended in %s: %s", self.name, where, exc)
            self.event("info", "stopped", f"ended in {where}: {exc}")
            return
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
        self.host.stage_failed(self.name)

    def wake(self) -> None:
        """Unblock every pump thread of this stage, and a publish waiting for a link's room (the run
        is stopping, or its data is done everywhere)."""
        for box in self.inboxes.values():
            box.close()
        for out in self.outputs.values():
            if out.wire is not None:
                out.wire.abort_links()
        for service in self.service_ports.values():
            service.wake()

    def teardown(self) -> None:
        if self.stage is not None:
            try:
                self.stage.teardown()
            except Exception as exc:
                self.stats.errors += 1
                self.stats.error = self.stats.error or f"teardown: {exc}"
                self.host.note_event(
                    Event(
                        level="error",
                        code="teardown_exception",
                        stage=self.name,
                        message=str(exc),
                        traceback=traceback.format_exc(),
                    )
                )
        self._close_port(EVENTS_PORT)
        for out in self.outputs.values():  # a stopped run: ports that did not end get no EOS
            if out.wire is not None:
                out.wire.close(timeout_s=2.0)
