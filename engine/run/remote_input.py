"""An input port fed by a stage of another process: its subscriber, its pump thread, its decoding.

The port is a zenoh subscriber with a FIFO channel handler on the producer's internal key
(engine.transport.bus.wire_key): zenoh's network thread only pushes each sample into the channel (no Python,
no GIL, never blocking below the channel's large capacity), and the port's pump thread
(:meth:`RemoteInput.pump`) takes the samples out in publication order, unpacks batches
(engine.transport.wire), decodes the messages and hands them to the stage through the runtime's deliver
function for the port, under the stage's lock. The port sees its runtime only as its
:class:`~engine.run.stage_host.PortOwner`. Samples already waiting are taken without releasing
the GIL; only an empty channel makes the thread block.

A sample that cannot be decoded is a warning event and is skipped; a damaged batch loses only its
own rest. Nothing here decides what a message means: the stage runtime (engine.run.runtime) does.
"""

from __future__ import annotations

import contextlib
import struct
from typing import TYPE_CHECKING, Any

from engine.messages import Message, codec
from engine.messages.codec import CodecError, Kind
from engine.run.inbox import END
from engine.transport.wire import BATCH_ENVELOPE, iter_batch

if TYPE_CHECKING:
    from engine.run.stage_host import Deliver, PortOwner

_DATA, _EOS = Kind.DATA, Kind.EOS  # (an Enum attribute lookup costs more than the test)
_decode_payload, _StructError = codec.decode_payload, struct.error


class RemoteInput:
    """Input *port* of stage runtime *rt*, fed from zenoh key *key* by a stage of another process;
    *deliver* hands each message (and the END) to the stage.

    ``close()`` undeclares the subscriber: the pump then gets what was already queued and an error,
    and ends."""

    def __init__(self, rt: PortOwner, port: str, key: str, deliver: Deliver) -> None:
        self.rt = rt
        self.port = port
        self.deliver = deliver
        self.closed = False
        self.subscriber, self.channel = rt.host.bus.subscribe_remote(key)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            with contextlib.suppress(Exception):  # already undeclared (the bus closes it too)
                self.subscriber.undeclare()

    def pump(self) -> None:
        """Thread body: receive, decode and handle the port's samples in order until its end.

        A sample is one message or a batch of them (engine.transport.wire), handled one by one in order. A
        DATA envelope of the port's own type is recognised by one struct call
        (:class:`engine.messages.codec.DataFormat`) and its payload decoded with the port's class; anything
        else takes the general path (:meth:`_decode_other`)."""
        rt = self.rt
        try_recv, recv = self.channel.try_recv, self.channel.recv
        stop_is_set, lock, deliver = rt.host.stop_event.is_set, rt.lock, self.deliver
        decode = self._decoder()
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
            # large payload would otherwise land on the next message's latency
            sample = att = payload = items = msg = None

    def _undecodable(self, exc: CodecError) -> None:
        if not self.rt.host.stop_event.is_set():
            self.rt.event("warning", "undecodable_message", f"ignored a message on input {self.port!r}: {exc}")

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
        if env.kind != _DATA:
            return None
        for obs in self.rt.host.observers:
            obs.on_receive(src.src, src.src_port, payload, raw_env)
        return codec.decode(payload, env)
