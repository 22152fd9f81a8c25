"""Stage-to-stage transport between vgr processes: one output port's sender, and the batch format.

A stage's messages reach its consumers in other vgr processes on the port's internal key
``vgr/<run>/_wire/<stage>/<port>`` (engine.transport.bus.wire_key); foreign subscribers (a robot controller, a
viewer) read the public key ``vgr/<run>/<stage>/<port>``, one message per sample, which vgr feeds
only while one listens. On the internal key a sample holds one message (payload + envelope, as on
the public key) or, while the producer publishes in a burst, a *batch*: several small messages in
one sample, whose envelope has kind BATCH and whose payload is the records

    struct "<II": envelope length, payload length; then the envelope; then the payload

in publication order. Why: zenoh-python's put costs 1.7-3 us while zenoh's transmit thread stays
busy, but 4-5 us when the caller does other work between puts (each put wakes that thread), and a
stage always does (it builds and encodes the message). Packing a burst into one sample pays that
once per batch.

:class:`WireSender` decides per message, in publication order:

* the port is idle (nothing waiting, nothing being sent) and the previous message left more than
  ``BURST_NS`` ago, or the payload is large: the publishing thread puts it at once — a paced stream
  (a camera, a control loop) never waits for anything, so its latency is that of a plain put;
* otherwise (a burst): the message joins the queue of the port's sender thread, which puts what has
  gathered — runs of small messages as batches of up to ``BATCH_BYTES``, large ones alone — and
  keeps going while the producer keeps adding. The queue is bounded (``MAX_PENDING`` messages,
  ``MAX_PENDING_BYTES`` of payload): a producer that outruns the network waits, nothing is dropped.

A payload of at least engine.transport.shm.SHM_MIN_BYTES goes, in this order of preference: as a
read-only view of the port's own pool (engine.transport.shm_views.ViewPool: a descriptor with kind
VIEW, while every consumer process maps this host's memory), or put from a zenoh shared-memory
buffer when the sender has a pool (engine.transport.shm.ShmPool: the session has shared memory on;
consumers on this host map it, others get the bytes through the network), or as bytes.

A consumer in another process of this host that took a link (engine.transport.local_link) gets the
same samples — single messages, batches, descriptors — as frames on its unix socket instead, written
by the same thread with one ``sendmsg``; zenoh is then put to only while some consumer has no link,
and a large payload goes as bytes, never from a zenoh buffer (a socket cannot carry one).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import zenoh

from engine.messages.codec import CodecError, Envelope, Kind, encode_envelope
from engine.transport.local_link import FRAME, LinkSender
from engine.transport.shm import ShmPool
from engine.transport.shm_views import ViewPayload, ViewPool, view_envelope

BATCH_ENVELOPE = encode_envelope(Envelope(Kind.BATCH, 0, 0, ""))
SMALL_BYTES = 16 * 1024  # payloads up to this size may share a sample
BATCH_BYTES = 60 * 1024  # a batch is put once it holds this much (zenoh's own batches are 64 KiB)
BURST_NS = 50_000  # a message this soon after the previous one of the port is part of a burst
MAX_PENDING = 4096  # messages a port may have waiting for its sender thread
# ... and payload bytes: a queue of thousands of 4 KiB messages (16 MB) no longer fits the CPU's
# caches, and every message then goes cold between the producer and the sender thread. Measured on
# 4 KiB messages between two processes (2 vCPUs, 1 MiB L2 per core): 86k msg/s with only the count
# bound, 118k with 128 KiB or 512 KiB of bytes; 64 B messages unchanged (the count bounds them).
MAX_PENDING_BYTES = 256 * 1024
_RECORD = FRAME  # a batch record and a link's frame: envelope length, payload length
_monotonic_ns = time.monotonic_ns


def _as_is(payload: bytes) -> bytes:
    return payload


def pack_batch(items: list[tuple[bytes, bytes]]) -> bytes:
    """One batch payload from (envelope, payload) pairs, in order."""
    pack = _RECORD.pack
    parts: list[bytes] = []
    for env, payload in items:
        parts += (pack(len(env), len(payload)), env, payload)
    return b"".join(parts)


def iter_batch(buf: bytes) -> Iterator[tuple[bytes, memoryview]]:
    """The (envelope, payload) pairs of a batch payload, in order; CodecError if it is malformed
    (the pairs before the damage have been yielded)."""
    view, off, end, head = memoryview(buf), 0, len(buf), _RECORD.size
    unpack = _RECORD.unpack_from
    while off < end:
        if end - off < head:
            raise CodecError(f"batch record header cut short at byte {off} of {end}")
        n_env, n_payload = unpack(buf, off)
        off += head
        if off + n_env + n_payload > end:
            raise CodecError(f"batch record at byte {off - head} runs past the end ({n_env}+{n_payload} > {end - off})")
        env = buf[off : off + n_env]
        off += n_env
        yield env, view[off : off + n_payload]
        off += n_payload


class WireSender:
    """Sends one output port's messages to its consumers in other processes (see the module
    docstring). :meth:`send` is called in publication order (the port's lock held)."""

    def __init__(self, publisher: Any, name: str, shm: ShmPool | None = None, views: ViewPool | None = None) -> None:
        self._publisher = publisher
        self._zput = publisher.put
        self._wrap = shm.wrap if shm is not None else _as_is  # large payloads into zenoh's shared memory
        # consumers of this host linked to the port (engine.transport.local_link)
        self._links: tuple[LinkSender, ...] = ()
        self._zenoh = True  # some consumer the graph names is not linked: zenoh gets every message too
        self._matching = True  # ... or some subscriber of the key is there (a process that rejoined)
        self._matching_listener: Any = None
        self._put = publisher.put  # (the port's puts: zenoh's own, until a consumer links)
        self._place = views.place if views is not None else None  # ... or as views of the port's pool
        self._name = name
        self._pending: list[tuple[bytes, bytes]] = []
        self._pending_bytes = 0  # payload bytes in _pending
        self._lock = threading.Lock()  # (entered directly on the hot path: a C context manager)
        self._cv = threading.Condition(self._lock)
        self._busy = False  # the sender thread is putting messages taken from the queue
        self._closed = False
        self._last_ns = 0
        self._error: BaseException | None = None  # a put of the sender thread failed
        self._thread: threading.Thread | None = None
        self.samples = 0  # zenoh samples put (batches count once)
        self.batched = 0  # messages that went in a batch

    def send(self, payload: bytes, envelope: bytes) -> None:
        """Send one message (raises, as a put would, once a put of the sender thread has failed)."""
        now = _monotonic_ns()
        with self._lock:
            if self._error is not None:
                raise self._failure()
            burst = now - self._last_ns < BURST_NS
            self._last_ns = now
            idle = not self._pending and not self._busy
            if self._closed or (idle and (not burst or len(payload) > SMALL_BYTES)):
                if len(payload) <= SMALL_BYTES:  # idle port: no hand-over, no wait
                    self._put(payload, attachment=envelope)
                else:
                    self._put_one(payload, envelope)
                self.samples += 1
                return
            while (
                (len(self._pending) >= MAX_PENDING or self._pending_bytes >= MAX_PENDING_BYTES)
                and not self._closed
                and self._error is None
            ):
                self._cv.wait()
            if self._error is not None:
                raise self._failure()
            self._pending.append((envelope, payload))
            self._pending_bytes += len(payload)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=f"vgr:wire:{self._name}", daemon=True)
                self._thread.start()
            elif len(self._pending) == 1:
                self._cv.notify_all()

    def add_link(self, link: LinkSender, zenoh_too: bool) -> None:
        """Send to *link* from now on (called before the port's first message); *zenoh_too*: some
        consumer is not linked, so zenoh still gets every message."""
        with self._lock:
            self._links = (*self._links, link)
            self._zenoh = zenoh_too
            self._wrap = _as_is  # a large payload goes as bytes: to the links, and to zenoh for another host
            self._put = self._fan_put
            if self._matching_listener is None:
                # a linked consumer no longer subscribes: once none is left, nothing is put there
                # (run on zenoh's thread: it only sets a flag)
                self._matching_listener = self._publisher.declare_matching_listener(
                    zenoh.handlers.Callback(self._on_matching, indirect=False)
                )
                self._matching = bool(self._publisher.matching_status.matching)

    def _on_matching(self, status: Any) -> None:
        self._matching = bool(status.matching)

    def _fan_put(self, payload: Any, attachment: bytes) -> None:
        """To every live link, and through zenoh while a consumer the graph names is not linked or
        something subscribes there (a process of the run started again takes its messages from
        zenoh: its port is past its first message). A link that fails is dropped (its consumer is
        gone or stuck, see engine.transport.local_link) and zenoh gets every message from then on,
        this one included; zenoh's put raises."""
        for link in self._links:
            if not link.send(attachment, payload):
                self._links = tuple(x for x in self._links if x is not link)
                self._zenoh = True
        if self._zenoh or self._matching:
            self._zput(payload, attachment=attachment)

    def abort_links(self) -> None:
        """Close the links now, a send waiting for room included (the run is stopping: no lock)."""
        for link in self._links:
            link.close()

    def _close_links(self) -> None:
        links, self._links = self._links, ()
        for link in links:
            link.close()

    def _failure(self) -> RuntimeError:
        err = RuntimeError(f"sending {self._name} to other processes failed: {self._error}")
        err.__cause__ = self._error
        return err

    def close(self, timeout_s: float = 10.0) -> None:
        """Put what is still queued, then stop the sender thread."""
        with self._cv:
            self._closed = True
            self._cv.notify_all()
            thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
        self._close_links()  # (after what was queued: a consumer reads to the end, then the link ends)

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._pending and not self._closed:
                    self._cv.wait()
                if not self._pending:
                    return
                items, self._pending = self._pending, []
                self._pending_bytes = 0
                self._busy = True
                self._cv.notify_all()  # a producer waiting for room
            try:
                self._put_items(items)
            except Exception as exc:  # the session is gone, say: the producer's next send raises it
                with self._cv:
                    self._error = exc
                    self._pending.clear()
                    self._pending_bytes = 0
                    self._busy = False
                    self._cv.notify_all()
                return
            with self._cv:
                self._busy = False

    def _put_items(self, items: list[tuple[bytes, bytes]]) -> None:
        run: list[tuple[bytes, bytes]] = []
        size = 0
        for env, payload in items:
            if len(payload) > SMALL_BYTES:
                self._put_run(run)
                run, size = [], 0
                self._put_one(payload, env)
                self.samples += 1
                continue
            run.append((env, payload))
            size += len(env) + len(payload) + _RECORD.size
            if size >= BATCH_BYTES:
                self._put_run(run)
                run, size = [], 0
        self._put_run(run)

    def _put_one(self, payload: Any, envelope: bytes) -> None:
        """One message in a sample of its own: a large one as a view of the port's pool when it
        can be, else from zenoh's shared memory or as bytes."""
        if type(payload) is not ViewPayload and self._place is not None and len(payload) > SMALL_BYTES:
            payload = self._place(payload) or payload
        if type(payload) is ViewPayload:
            self._put(payload.descriptor, attachment=view_envelope(envelope))
        elif self._links:
            self._put(payload, attachment=envelope)  # (bytes: a link cannot carry a zenoh buffer)
        else:
            self._zput(self._wrap(payload), attachment=envelope)

    def _put_run(self, run: list[tuple[bytes, bytes]]) -> None:
        if not run:
            return
        if len(run) == 1:
            env, payload = run[0]
            self._put(payload, attachment=env)
        else:
            self._put(pack_batch(run), attachment=BATCH_ENVELOPE)
            self.batched += len(run)
        self.samples += 1
