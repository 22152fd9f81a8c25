"""The stage-to-stage transport between processes (engine.transport.wire): batch format, the sender's order,
batching and back-pressure, and, end to end, a burst batched on the internal key while a foreign
subscriber of the public key still gets one message per sample."""

from __future__ import annotations

import json
import threading
import time

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from process_helpers import free_port
from recipe_helpers import graph_from
from stage_fixtures import COLLECTED

from engine.messages import codec
from engine.messages.codec import CodecError, Envelope, Kind
from engine.run.runner import Runner
from engine.transport import wire
from engine.transport.bus import data_key

pytestmark = pytest.mark.timeout(90)


def env_of(seq: int) -> bytes:
    return codec.encode_envelope(Envelope(Kind.DATA, seq, 1000 + seq, "Blob"))


class FakePublisher:
    """Records what is put, in order."""

    def __init__(self) -> None:
        self.samples: list[tuple[bytes, bytes]] = []

    def put(self, payload: bytes, attachment: bytes) -> None:
        self.samples.append((bytes(payload), bytes(attachment)))

    def messages(self) -> list[tuple[bytes, bytes]]:
        """(envelope, payload) of every message, batches unpacked, in the order they went out."""
        out = []
        for payload, att in self.samples:
            if att == wire.BATCH_ENVELOPE:
                out += [(bytes(e), bytes(p)) for e, p in wire.iter_batch(payload)]
            else:
                out.append((att, payload))
        return out


def test_batch_round_trip_and_damage():
    items = [(env_of(i), bytes([i]) * i) for i in range(1, 20)] + [(env_of(20), b"")]
    buf = wire.pack_batch(items)
    assert [(e, bytes(p)) for e, p in wire.iter_batch(buf)] == items
    got = []
    with pytest.raises(CodecError, match="runs past the end"):
        for e, p in wire.iter_batch(buf[:-5] + b"\xff" * 2):  # the last record cut
            got.append((e, bytes(p)))
    assert got == items[:-1] or got == items[:-2]


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_garbled_batches_only_raise_codec_errors(data):
    """What iter_batch yields is exactly the bytes it was given, record by record: all of them, or
    the records before the damage when it raises CodecError."""
    got: list[tuple[bytes, bytes]] = []
    try:
        for env, payload in wire.iter_batch(data):
            got.append((bytes(env), bytes(payload)))
    except CodecError:
        assert data.startswith(wire.pack_batch(got)) and len(wire.pack_batch(got)) < len(data)
    else:
        assert wire.pack_batch(got) == data


def test_sender_keeps_publication_order_and_batches_a_burst():
    pub = FakePublisher()
    sender = wire.WireSender(pub, "t")
    sent = []
    for seq in range(1, 3001):
        payload = bytes(20_000) if seq % 500 == 0 else seq.to_bytes(4, "little")  # a few large ones
        sender.send(payload, env_of(seq))
        sent.append((env_of(seq), payload))
    eos = codec.encode_envelope(Envelope(Kind.EOS, 3001, 0, ""))
    sender.send(b"", eos)
    sender.close()
    assert pub.messages() == [*sent, (eos, b"")]
    assert sender.batched > 100 and len(pub.samples) < 3001  # back-to-back messages shared samples
    assert all(len(p) <= wire.BATCH_BYTES + 20_000 for p, _ in pub.samples)


def test_a_paced_stream_is_put_at_once_by_the_publisher():
    pub = FakePublisher()
    sender = wire.WireSender(pub, "t")
    for seq in range(1, 21):
        sender.send(b"x", env_of(seq))
        time.sleep(2 * wire.BURST_NS / 1e9)
        assert len(pub.samples) == seq  # already out when send returned: no queue, no thread
    assert sender._thread is None and sender.batched == 0
    sender.close()


class SlowBatches(FakePublisher):
    """A slow link for the sender thread's batches only (a message put at once by an idle port is
    fast, so the producer runs into a burst); after each put notes what the producer queued meanwhile."""

    def __init__(self) -> None:
        super().__init__()
        self.sender: wire.WireSender | None = None
        self.queued: list[tuple[int, int]] = []  # (messages, payload bytes) waiting after each put

    def put(self, payload: bytes, attachment: bytes) -> None:
        if attachment == wire.BATCH_ENVELOPE:
            time.sleep(0.002)
        super().put(payload, attachment)
        assert self.sender is not None
        self.queued.append((len(self.sender._pending), self.sender._pending_bytes))


def send_over_slow_link(n: int, payload: bytes) -> SlowBatches:
    """Send *n* messages through a WireSender over SlowBatches and close it; all arrive, in order."""
    pub = SlowBatches()
    sender = pub.sender = wire.WireSender(pub, "t")
    for seq in range(1, n + 1):
        sender.send(payload, env_of(seq))
    sender.close()
    assert [e for e, _ in pub.messages()] == [env_of(s) for s in range(1, n + 1)]
    return pub


def test_a_slow_link_makes_the_producer_wait_and_loses_nothing(monkeypatch):
    monkeypatch.setattr(wire, "MAX_PENDING", 8)
    # every send after the first counts as a burst however slowly a loaded machine runs this loop
    # (an idle port that is not in a burst puts at once, past the queue)
    monkeypatch.setattr(wire, "BURST_NS", 10**15)
    pub = send_over_slow_link(200, b"y" * 10)
    assert pub.sender is not None and pub.sender.batched > 100  # the burst went through the sender thread's queue
    assert max(n for n, _ in pub.queued) == 8  # which filled up to its bound and no further


def test_the_queue_is_bounded_in_bytes_too(monkeypatch):
    """Few large messages fill the byte bound long before the count bound: the producer waits."""
    monkeypatch.setattr(wire, "MAX_PENDING_BYTES", 1000)
    monkeypatch.setattr(wire, "BURST_NS", 10**15)  # (as above: a burst however slow the machine)
    pub = send_over_slow_link(100, b"w" * 100)
    queued_bytes = [b for _, b in pub.queued]
    assert max(queued_bytes) >= 900  # the queue did fill up to the bound ...
    assert max(queued_bytes) < 1000 + 100  # ... and no further: one payload past it at most


def test_a_failed_put_of_the_sender_thread_fails_the_next_send():
    class Broken(FakePublisher):
        def put(self, payload: bytes, attachment: bytes) -> None:
            if len(self.samples) >= 1:
                raise ConnectionError("session closed")
            super().put(payload, attachment)

    sender = wire.WireSender(Broken(), "src.out")
    with pytest.raises(RuntimeError, match=r"sending src\.out to other processes failed: session closed"):
        for seq in range(1, 10_000):  # a burst: queued for the sender thread, whose second put fails
            sender.send(b"z", env_of(seq))
    sender.close()


RECIPE = """
name: wire_t
plugins: [stage_fixtures]
run_id: {rid}
processes:
  a: {{listen: ["tcp/127.0.0.1:{port_a}"], connect: ["tcp/127.0.0.1:{port_f}"]}}
  b: {{connect: ["tcp/127.0.0.1:{port_a}"], listen: []}}
stages:
  src:  {{type: t_counter, process: a, params: {{n: {n}}}}}
  sink: {{type: t_collector, process: b, inputs: {{in: src.out}}}}
"""


def test_a_burst_is_batched_between_processes_while_a_foreign_subscriber_gets_single_messages():
    rid, n = "wire_t1", 3000
    port_a, port_f = free_port(), free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port_f}"]))
    foreign = zenoh.open(conf)  # a viewer: listens first, so process a connects to it on start
    seen: list[bytes] = []
    sub = foreign.declare_subscriber(data_key(rid, "src", "out"), lambda s: seen.append(s.attachment.to_bytes()))
    text = RECIPE.format(rid=rid, port_a=port_a, port_f=port_f, n=n)
    runners = {p: Runner(graph_from(text), process=p, ready_timeout_s=20) for p in ("a", "b")}
    results: dict[str, object] = {}
    threads = [threading.Thread(target=lambda p=p: results.update({p: runners[p].run()})) for p in ("b", "a")]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert not any(t.is_alive() for t in threads)
        time.sleep(0.2)
    finally:
        sub.undeclare()
        foreign.close()
    assert all(results[p].ok for p in "ab"), {p: results[p].stop_reason for p in "ab"}  # type: ignore[attr-defined]
    rows = COLLECTED[rid]["sink"]
    assert [r["seq"] for r in rows] == list(range(1, n + 1))
    assert runners["a"].runtimes["src"].outputs["out"].wire.batched > 0  # the burst shared samples
    # the viewer: one vgr message per sample, never a batch, in order, through the end of stream
    envs = [codec.decode_envelope(a) for a in seen]
    assert envs and all(e.kind in (Kind.DATA, Kind.EOS) for e in envs)
    seqs = [e.seq for e in envs if e.kind == Kind.DATA]
    assert seqs == list(range(seqs[0], n + 1)) and envs[-1].kind == Kind.EOS
