"""An input port fed by a stage of another process: its subscriber, where its messages are handed
to the stage, its decoding.

A sample is one message or a batch of them (engine.transport.wire), in publication order; a large
payload of a producer on this host may come as a descriptor of a block of the producer's shared
memory (envelope kind VIEW, engine.transport.shm_views), which the port turns into a read-only view
of that block: the codec decodes the bulk array as a numpy view of it, no copy on receive.

A producer on this host sends them over a link instead (engine.transport.local_link, asked for by
:meth:`RemoteInput.try_link` before the stages start): a thread of this input reads the link and
hands each message to the stage itself while the stage is idle and its handler quick (the rule of
zenoh's receive thread below; one thread wake-up from the producer's send to the handler; the
thread serves this input alone, so a handler may wait there for anything), else queues it for the
port's pump and reads on; zenoh's samples of the port are ignored.

Otherwise, where the stage gets the messages from zenoh is decided per stage from what the engine
knows of it (:func:`receive_thread_safe`), not by a user flag:

* **on zenoh's receive thread** (``Bus.subscribe_direct``: the callback runs there, no hand-over to
  another thread) when that cannot hold anything up: the stage calls no service (a handler waiting
  for a reply on the thread that delivers replies would wait for ever), none of its outputs goes to
  another process (a put with congestion control BLOCK could wait for a process whose own receive
  thread waits on ours), the same holds for every stage of this process its outputs feed (an idle
  local consumer runs on the caller's thread, engine.run.inbox), and its ``dispatch`` is ``auto``.
  Even then a message goes there only while the stage is idle (nothing queued, lock free) and the
  port's handler has been quick: it starts on the stage's thread and moves to the receive thread
  after :data:`RX_TRIAL` handlings in a row under :data:`RX_BUDGET_S`; one over it moves it back
  (every other message and reply of that link waits while a handler runs there, and a link that
  reads nothing for zenoh's lease is closed). The end of stream never goes there (it runs the
  stage's ``finish()``, which may take long). Otherwise the message waits in the port's queue
  (unbounded: the receive thread never waits) for the port's pump thread;
* **on the port's pump thread** for every other stage: a zenoh FIFO channel (zenoh's network
  thread only pushes each sample in; no Python, no GIL, never blocking below the channel's large
  capacity) read by :meth:`RemoteInput.pump`, which decodes and hands over under the stage's lock.

Measured (benchmarks/shm_view.py, 64 B between two processes paced 1 ms): the hand-over costs one
thread wake-up, which on this shared VM is 5-70 us depending on how deeply the core slept.

A sample that cannot be decoded is a warning event and is skipped; a damaged batch loses only its
own rest. Nothing here decides what a message means: the stage runtime (engine.run.runtime) does.
The port sees its runtime only as its :class:`~engine.run.stage_host.PortOwner`.
"""

from __future__ import annotations

import contextlib
import logging
import struct
from time import perf_counter
from typing import TYPE_CHECKING, Any

from engine.messages import Message, codec
from engine.messages.codec import CodecError, Kind
from engine.run.inbox import END, STOP, PortInbox
from engine.transport.local_link import FrameReader, open_link
from engine.transport.shm_views import ViewReader, consumer_order, data_envelope_of
from engine.transport.wire import BATCH_ENVELOPE, iter_batch

if TYPE_CHECKING:
    from engine.graph import Graph
    from engine.run.stage_host import Deliver, PortOwner

log = logging.getLogger("vgr.remote_input")
_DATA, _EOS, _VIEW = Kind.DATA, Kind.EOS, Kind.VIEW  # (an Enum attribute lookup costs more than the test)
_decode_payload, _StructError = codec.decode_payload, struct.error
RX_BUDGET_S = 0.002  # a handler on zenoh's receive thread must stay under this ...
RX_TRIAL = 8  # ... this many times in a row on the stage's own thread before it moves there


def receive_thread_safe(graph: Graph, stage: str, _seen: dict[str, bool] | None = None) -> bool:
    """Whether *stage*'s inputs from other processes may be handled on zenoh's receive thread (see
    the module docstring): no service client wired, ``dispatch: auto``, every output's consumers in
    its own process and safe by the same rule."""
    seen = {} if _seen is None else _seen
    if stage in seen:
        return seen[stage]
    seen[stage] = False  # (a DAG: no stage is its own consumer; this guards a malformed graph)
    node = graph.nodes[stage]
    process = node.spec.process
    ok = node.spec.dispatch == "auto" and not any(e.client == stage for e in graph.service_edges)
    for port in node.cls.all_outputs() if ok else ():
        for e in graph.consumers_of(stage, port):
            if graph.nodes[e.dst].spec.process != process or not receive_thread_safe(graph, e.dst, seen):
                ok = False
                break
        if not ok:
            break
    seen[stage] = ok
    return ok


class RemoteInput:
    """Input *port* of stage runtime *rt*, fed from zenoh key *key* by a stage of another process;
    *deliver* hands each message (and the END) to the stage. With *on_receive_thread* (see
    :func:`receive_thread_safe`) it may be handed over on zenoh's receive thread.

    ``close()`` ends the pump: on the channel path it undeclares the subscriber (the pump gets what
    was queued, then an error); on the receive-thread path later samples are ignored and the pump
    takes its STOP."""

    def __init__(
        self, rt: PortOwner, port: str, key: str, deliver: Deliver, *, on_receive_thread: bool = False
    ) -> None:
        self.rt = rt
        self.port = port
        self.deliver = deliver
        self.closed = False
        bus = rt.host.bus
        self.views = self._view_reader()
        self._decode = self._decoder()
        self.queue: PortInbox | None = None
        self.channel: Any = None
        self.on_receive_thread = False  # messages are handed over there now (after RX_TRIAL quick ones)
        self._quick = 0  # handlings in a row under RX_BUDGET_S
        self._host = rt.host  # (bound once for the receive thread's path)
        self._lock: Any = rt.lock  # (an RLock: acquired without waiting there)
        self.link: FrameReader | None = None  # the producer sends this input's messages here (try_link), not zenoh
        if on_receive_thread:
            self.queue = PortInbox(port, None)  # unbounded: the receive thread never waits
            self.subscriber = bus.subscribe_direct(key, self._on_sample)
        else:
            self.subscriber, self.channel = bus.subscribe_remote(key)
        if self.views is not None:  # this process maps views (after the subscriber: none is sent to no one)
            bus.host_peers(rt.host.run_id, rt.node.spec.process)

    def _view_reader(self) -> ViewReader | None:
        rt = self.rt
        bus, graph = rt.host.bus, rt.host.graph
        if getattr(bus, "shm", None) is None:
            return None
        src = next(e for e in graph.inputs_of(rt.name) if e.dst_port == self.port)
        producer = graph.nodes[src.src].spec.process
        consumers = consumer_order(
            [
                (graph.nodes[e.dst].spec.process, e.dst, e.dst_port)
                for e in graph.consumers_of(src.src, src.src_port)
                if graph.nodes[e.dst].spec.process != producer
            ]
        )
        return ViewReader(consumers.index((rt.node.spec.process, rt.name, self.port)))

    def try_link(self, host: str) -> bool:
        """Ask the producer, if it is a process of this host, to send this input's messages over a
        link (engine.transport.local_link; *host*: this host's key; before the stages start: the
        producer takes the link only while the port has published nothing). Taken: zenoh's copies
        are ignored from now on (the producer may still put them for another consumer) and a
        thread reads the link."""
        rt = self.rt
        graph, run = rt.host.graph, rt.host.run_id
        src = next(e for e in graph.inputs_of(rt.name) if e.dst_port == self.port)
        hello = {"v": 1, "run": run, "stage": src.src, "port": src.src_port, "host": host}
        hello |= {"process": rt.node.spec.process, "consumer": rt.name, "input": self.port}
        sock = open_link(run, graph.nodes[src.src].spec.process, hello)
        if sock is None:
            return False
        self.link = FrameReader(sock)  # (before the swap below: a zenoh sample in flight then sees it)
        with contextlib.suppress(Exception):
            self.subscriber.undeclare()
        self.channel = None  # what zenoh had queued came after the link was taken: the link has it too
        self.queue = PortInbox(self.port, None)  # unbounded: the link's reader never waits
        rt.spawn_thread(f"{rt.name}.{self.port}.link", self._read_link, self.link)
        # (the run folder's run.log says it; not an event of the stage: a replay, in one process,
        # must record the same events)
        log.info("%s: input %r takes %s.%s over a unix socket of this host", rt.name, self.port, src.src, src.src_port)
        return True

    def _read_link(self, link: FrameReader) -> None:
        """Thread body: the link's frames, in order, handed to the stage (:meth:`_offer_linked`)
        until the producer ends the link."""
        decode, offer = self._decode, self._offer_linked
        try:
            for raw_env, payload in link.frames():
                items = iter_batch(payload) if raw_env == BATCH_ENVELOPE else iter(((raw_env, payload),))
                try:
                    for env, body in items:
                        try:
                            msg = decode(env, body)
                        except CodecError as exc:
                            self._undecodable(exc)
                            continue
                        if msg is not None:
                            offer(msg)
                except CodecError as exc:  # the batch itself is damaged: the rest of it is lost
                    self._undecodable(exc)
                msg = payload = items = None
        except Exception:  # (the thread ends; the stage sees the producer's stream end or the stop)
            log.exception("input %s.%s: its link failed", self.rt.name, self.port)

    def _offer_linked(self, msg: Message | object) -> None:
        """Hand *msg* to the stage on the link's own thread when the stage is idle and its handler
        has been quick (as on zenoh's receive thread: :data:`RX_TRIAL` handlings under
        :data:`RX_BUDGET_S`, one over it moves it back), else queue it for the pump: while a handler
        runs here the link is not read, and a producer that fills the socket waits. (This thread
        serves only this input: a handler may wait here for anything, a service's reply included.)"""
        inline = self.on_receive_thread and msg is not END and self._host.started
        self._hand_over(self.queue, msg, inline, self._timed_deliver)  # type: ignore[arg-type]

    def _hand_over(self, queue: PortInbox, msg: Message | object, inline: bool, deliver: Deliver) -> None:
        """*deliver(msg)* on this thread when *inline* and the stage is idle (nothing queued or in
        flight, its lock free), else queue *msg* for the port's pump."""
        if inline and queue.claim_idle():
            lock = self._lock
            if lock.acquire(False):
                try:
                    deliver(msg)
                finally:
                    lock.release()
                    queue.release()
                return
            queue.release()
        queue.put(msg, block=False)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.link is not None:
            self.link.close()  # its reader's next read ends
        if self.queue is not None:  # (the subscriber goes with the bus: never undeclared from its own callback)
            self.queue.close()
            return
        with contextlib.suppress(Exception):  # already undeclared (the bus closes it too)
            self.subscriber.undeclare()

    def pump(self) -> None:
        """Thread body: handle the port's messages in order until its end (the channel's samples, or
        on the receive-thread path what had to wait in the queue)."""
        try:
            if self.queue is not None:
                self._pump_queue(self.queue)
            else:
                self._pump_channel()
        finally:
            if self.views is not None:
                self.views.close()

    def _pump_channel(self) -> None:
        """Receive, decode and handle the channel's samples in order.

        A DATA envelope of the port's own type is recognised by one struct call
        (:class:`engine.messages.codec.DataFormat`) and its payload decoded with the port's class; anything
        else takes the general path (:meth:`_decode_other`)."""
        rt = self.rt
        try_recv, recv = self.channel.try_recv, self.channel.recv
        stop_is_set, lock, deliver = rt.host.stop_event.is_set, rt.lock, self.deliver
        decode = self._decode
        while True:
            try:
                sample = try_recv()
                if sample is None:
                    sample = recv()  # blocks with the GIL released
            except Exception:  # the channel is closed (subscriber undeclared) and empty
                return
            if stop_is_set():
                return
            att = sample.attachment
            raw_env = att.to_bytes() if att is not None else b""
            payload = sample.payload.to_bytes()
            if raw_env == BATCH_ENVELOPE:
                items = iter_batch(payload)
            else:
                items = iter(((raw_env, payload),))
            try:
                for raw_env, payload in items:
                    try:
                        msg = decode(raw_env, payload)
                    except CodecError as exc:
                        self._undecodable(exc)
                        continue
                    if msg is None:
                        continue
                    with lock:
                        deliver(msg)
                    if msg is END:
                        return
            except CodecError as exc:  # the batch itself is damaged: the rest of it is lost
                self._undecodable(exc)
            # drop the message and its buffers now, not when the next one has arrived: freeing a
            # large payload would otherwise land on the next message's latency (and a view's block
            # goes back to its sender)
            sample = att = payload = items = msg = None

    # -- the receive-thread path -------------------------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        """zenoh's receive thread: decode the sample's messages and hand each over (never waits)."""
        if self.closed:
            return
        try:
            att = sample.attachment
            raw_env = att.to_bytes() if att is not None else b""
            payload = sample.payload.to_bytes()
            if raw_env != BATCH_ENVELOPE:
                try:
                    msg = self._decode(raw_env, payload)
                except CodecError as exc:
                    self._undecodable(exc)
                    return
                if msg is not None:
                    self._offer(msg)
                return
            try:
                for env, body in iter_batch(payload):
                    try:
                        msg = self._decode(env, body)
                    except CodecError as exc:
                        self._undecodable(exc)
                        continue
                    if msg is not None:
                        self._offer(msg)
            except CodecError as exc:  # the batch itself is damaged: the rest of it is lost
                self._undecodable(exc)
        except Exception:  # nothing may escape into zenoh's thread
            log.exception("input %s.%s: a sample could not be handled", self.rt.name, self.port)

    def _offer(self, msg: Message | object) -> None:
        """Hand *msg* to the stage here when the stage is idle and quick, else queue it for the pump."""
        queue = self.queue
        if self.link is not None:  # (read after the queue: try_link sets it before it swaps the queue)
            return
        # (the END always goes to the pump: it runs the stage's finish(), which may take long)
        inline = self.on_receive_thread and msg is not END and self._host.started
        self._hand_over(queue, msg, inline, self._timed_deliver)  # type: ignore[arg-type]

    def _timed_deliver(self, msg: Message | object) -> None:
        """Deliver *msg* (the stage's lock held) and keep score of the handler's time."""
        t0 = perf_counter()
        self.deliver(msg)
        if perf_counter() - t0 < RX_BUDGET_S:
            if not self.on_receive_thread:
                self._quick += 1
                if self._quick >= RX_TRIAL and not self.closed:
                    self.on_receive_thread = True
        else:
            self._quick = 0
            self.on_receive_thread = False

    def _pump_queue(self, queue: PortInbox) -> None:
        """The pump of the receive-thread path: what waited in the queue, in order."""
        lock = self.rt.lock
        while True:
            msg = queue.get()
            try:
                if msg is STOP:
                    return
                with lock:
                    self._timed_deliver(msg)
                if msg is END:
                    return
            finally:
                queue.release()
            msg = None

    def _undecodable(self, exc: CodecError) -> None:
        if not self.rt.host.stop_event.is_set():
            self.rt.event("warning", "undecodable_message", f"ignored a message on input {self.port!r}: {exc}")

    def _view_of(self, descriptor: bytes | memoryview) -> memoryview:
        """The payload a VIEW descriptor names (engine.transport.shm_views). When it cannot be mapped,
        this process stops saying it maps this host's memory, so the producer sends bytes from then
        on; the message itself is lost (CodecError: a warning, and the next one's seq shows the gap)."""
        if self.views is None:
            raise CodecError("a shared-memory descriptor, but this process has shared memory off")
        try:
            return self.views.payload(descriptor)
        except CodecError:
            rt = self.rt
            rt.host.bus.host_peers(rt.host.run_id, rt.node.spec.process).withdraw()
            raise

    def _decoder(self) -> Any:
        """``decode(raw_env, payload)``: the port's message, END, or None (ignore); raises
        CodecError. Run observers (the recorder) see every data message as it arrives."""
        rt = self.rt
        observers = rt.host.observers
        cls = rt.node.cls.inputs[self.port]
        fmt = codec.DataFormat(cls.TYPE)
        unpack, head, name = fmt.unpack, fmt.head, fmt.name
        src = next(e for e in rt.host.graph.inputs_of(rt.name) if e.dst_port == self.port)
        decode_other = self._decode_other

        def decode(raw_env: bytes, payload: bytes | memoryview) -> Message | object | None:
            try:
                h, seq, stamp, n = unpack(raw_env)
            except _StructError:
                return decode_other(src, raw_env, payload)
            if h != head or n != name:
                return decode_other(src, raw_env, payload)
            if observers:
                for obs in observers:
                    obs.on_receive(src.src, src.src_port, payload, raw_env)
            msg = _decode_payload(cls, payload)
            msg.seq = seq
            if not msg.stamp_ns:
                msg.stamp_ns = stamp
            return msg

        return decode

    def _decode_other(self, src: Any, raw_env: bytes, payload: bytes | memoryview) -> Message | object | None:
        """A message the fast path did not recognise: a message of another type or schema version,
        an end of stream (END), or something to ignore (None). Raises CodecError."""
        env = codec.decode_envelope(raw_env)
        if env.kind == _EOS:
            return END
        if env.kind == _VIEW:  # a block of the producer's shared memory: a read-only view of it
            payload = self._view_of(payload)
            raw_env, env = data_envelope_of(raw_env), env._replace(kind=_DATA)
        elif env.kind != _DATA:
            return None
        for obs in self.rt.host.observers:
            obs.on_receive(src.src, src.src_port, payload, raw_env)
        return codec.decode(payload, env)
