"""Large payloads as read-only views of the sender's shared memory (engine.transport.shm_views), at
the level of the pool and the reader: a view's lifetime, a full pool, nothing leaking over many
messages, and where a remote input hands its messages over (engine.run.remote_input).

Sender and receiver are in this process here (a pool's memfd opens through ``/proc/<pid>/fd`` from
this process as from another); tests/engine_core/test_shm_views_processes.py has them in separate
processes, killed mid-run, and across two network namespaces.
"""

from __future__ import annotations

import gc
import os
from pathlib import Path

import numpy as np
import pytest
from recipe_helpers import graph_from

from engine.messages import PointCloud, codec
from engine.messages.codec import CodecError
from engine.run.remote_input import receive_thread_safe
from engine.transport import shm_views
from engine.transport.shm_views import MAX_BLOCKS, ViewPayload, ViewPool, ViewReader

pytestmark = pytest.mark.timeout(120)

LARGE = 1_200_000


class Peers:
    """Stands for HostPeers: every consumer process maps this host's memory, with one session."""

    host = "test"

    def __init__(self, processes: list[str]) -> None:
        self.sessions = {p: frozenset({f"zid-{p}"}) for p in processes}

    def zids(self, process: str) -> frozenset[str]:
        return self.sessions.get(process, frozenset())


def pool_and_reader(size: int = 8 * LARGE) -> tuple[ViewPool, ViewReader, Peers]:
    peers = Peers(["b"])
    pool = ViewPool(peers, [("b", "sink", "cloud")], size=size)  # type: ignore[arg-type]
    return pool, ViewReader(0), peers


def payload(k: int, n: int = LARGE) -> bytes:
    return ((np.arange(n, dtype=np.int64) * 7 + k) % 251).astype(np.uint8).tobytes()


def mapped_pools() -> int:
    return sum("memfd:vgr-views" in line for line in Path("/proc/self/maps").read_text().splitlines())


def test_a_view_is_read_only_and_holds_its_block_until_the_last_reference_goes():
    pool, reader, _ = pool_and_reader()
    placed = pool.place(payload(0))
    assert isinstance(placed, ViewPayload)
    view = np.frombuffer(reader.payload(placed.descriptor), dtype=np.uint8)
    with pytest.raises(ValueError, match="read-only"):
        view[0] = 1  # never written through
    for k in range(1, 40):  # many more messages while the view is held: its block is not reused
        other = pool.place(payload(k))
        assert other is not None
        np.frombuffer(reader.payload(other.descriptor), dtype=np.uint8)  # (dropped at once: released)
    assert view.tobytes() == payload(0)
    assert pool.in_flight() == 1  # only the block still referred to
    part = view[1000:2000]  # a slice keeps it too
    del view
    assert pool.in_flight() == 1 and part.tobytes() == payload(0)[1000:2000]
    del part
    assert pool.in_flight() == 0


def test_a_decoded_cloud_is_a_view_of_the_block_and_keeps_it():
    pool, reader, _ = pool_and_reader()
    pts = np.random.default_rng(1).normal(size=(50_000, 3))
    head, bulk = codec.encode_parts(PointCloud(points=pts, frame_id="f"))
    placed = pool.place(head, bulk)
    assert placed is not None
    cloud = codec.decode_payload(PointCloud, reader.payload(placed.descriptor))
    assert not cloud.points.flags.writeable and np.array_equal(cloud.points, pts)
    assert pool.in_flight() == 1
    kept = np.array(cloud.points)  # what a stage that keeps clouds does: its own copy
    del cloud
    assert pool.in_flight() == 0 and np.array_equal(kept, pts) and kept.flags.writeable


def test_a_full_pool_sends_the_other_way_after_a_short_wait_and_views_again_once_released():
    pool, reader, _ = pool_and_reader(size=3 * LARGE)  # (a pool holds at least 8 of its first payload)
    held = []
    for k in range(12):
        placed = pool.place(payload(k))
        if placed is None:
            break
        held.append(np.frombuffer(reader.payload(placed.descriptor), dtype=np.uint8))
    assert 8 <= len(held) < 12 and pool.fallbacks == 1  # full: the caller sends bytes
    assert [h.tobytes() for h in held] == [payload(k) for k in range(len(held))]  # held ones intact
    held.pop(0)
    again = pool.place(payload(99))
    assert again is not None
    assert np.frombuffer(reader.payload(again.descriptor), dtype=np.uint8).tobytes() == payload(99)


def test_a_consumer_whose_sessions_are_gone_is_not_waited_for():
    pool, reader, peers = pool_and_reader(size=2 * LARGE)
    held = [np.frombuffer(reader.payload(p.descriptor), np.uint8) for p in (pool.place(payload(0)),) if p]
    assert pool.in_flight() == 1
    peers.sessions["b"] = frozenset({"zid-b-restarted"})  # the consumer was killed, another started
    assert pool.in_flight() == 0 and held[0].tobytes() == payload(0)  # (this mapping stays valid)
    peers.sessions.clear()  # no consumer maps this host now: no views at all
    assert pool.place(payload(1)) is None


def test_small_payloads_and_consumers_elsewhere_get_no_view():
    pool, _, peers = pool_and_reader()
    assert pool.place(b"x" * (shm_views.VIEW_MIN_BYTES - 1)) is None
    peers.sessions.clear()
    assert pool.place(payload(0)) is None and pool.shared == 0


def test_a_descriptor_of_a_pool_that_is_not_there_is_a_codec_error():
    pool, reader, _ = pool_and_reader()
    placed = pool.place(payload(0))
    assert placed is not None
    desc = bytearray(placed.descriptor)
    desc[12:28] = bytes(16)  # another nonce: a reused pid's descriptor, say
    with pytest.raises(CodecError, match="not the sender's pool"):
        reader.payload(bytes(desc))
    with pytest.raises(CodecError, match="descriptor"):
        reader.payload(b"short")


BODY = bytes(range(256)) * 300  # 76.8 kB, above the threshold


def cycle(pool: ViewPool, reader: ViewReader, n: int) -> None:
    """*n* messages placed, viewed, read and dropped, one after the other."""
    for k in range(n):
        placed = pool.place(b"h%d" % (k % 10), memoryview(BODY))
        assert placed is not None
        view = reader.payload(placed.descriptor)
        assert view[-1] == BODY[-1]
        del view


def leak_check(n: int) -> None:
    pool, reader, _ = pool_and_reader(size=4 * 1024 * 1024)
    cycle(pool, reader, 200)  # warm: the pool exists and is mapped
    fds, maps = len(os.listdir("/proc/self/fd")), mapped_pools()
    cycle(pool, reader, n)
    assert pool.in_flight() == 0 and pool.fallbacks == 0 and pool.shared == n + 200
    assert len(os.listdir("/proc/self/fd")) == fds and mapped_pools() == maps == 3  # sender 1, reader 2
    reader.close()
    pool.close()
    gc.collect()
    assert mapped_pools() == 0  # nothing of the pool is left in this process


def test_nothing_leaks_over_many_messages():
    """20 000 here; the same check over a million messages is ``python benchmarks/shm_view.py --leak
    1000000`` (results/shm_view_leak.json)."""
    leak_check(20_000)


def test_the_block_table_bounds_the_messages_in_flight():
    pool, reader, _ = pool_and_reader(size=MAX_BLOCKS * 2 * 70_000)
    held = []
    while (placed := pool.place(BODY[:70_000])) is not None and len(held) <= MAX_BLOCKS:
        held.append(reader.payload(placed.descriptor))
    assert len(held) == MAX_BLOCKS and pool.fallbacks == 1


# --------------------------------------------------------------------------- where the hand-over is

GRAPH = """
name: rx_thread
plugins: [stage_fixtures]
processes:
  a: {{}}
  b: {{}}
stages:
  src:    {{type: t_counter, process: a, params: {{n: 1}}}}
  svc:    {{type: t_echo, process: a}}
  sink:   {{type: t_collector, process: b, inputs: {{in: src.out}}, dispatch: {dispatch}}}
  relay:  {{type: t_relay, process: b, inputs: {{in: src.out}}}}
  after:  {{type: t_collector, process: b, inputs: {{in: relay.out}}}}
  far:    {{type: t_relay, process: b, inputs: {{in: src.out}}}}
  back:   {{type: t_collector, process: a, inputs: {{in: far.out}}}}
  caller: {{type: t_caller, process: b, inputs: {{in: src.out}}, uses: {{svc: svc.echo}}}}
  feeds_caller: {{type: t_relay, process: b, inputs: {{in: src.out}}}}
  called: {{type: t_caller, process: b, inputs: {{in: feeds_caller.out}}, uses: {{svc: svc.echo}}}}
"""


def test_only_stages_that_cannot_wait_on_the_receive_thread_are_handed_messages_there():
    graph = graph_from(GRAPH.format(dispatch="auto"))
    safe = {name: receive_thread_safe(graph, name) for name in ("sink", "relay", "far", "caller", "feeds_caller")}
    assert safe == {
        "sink": True,  # calls nothing, publishes nothing
        "relay": True,  # its output stays in this process, to a stage that is safe too
        "far": False,  # its output goes to another process (a put that may wait)
        "caller": False,  # calls a service: its reply comes on the receive thread
        "feeds_caller": False,  # an idle local consumer runs on the caller's thread, and that one calls
    }
    own_thread = graph_from(GRAPH.format(dispatch="thread"))
    assert receive_thread_safe(own_thread, "sink") is False  # the recipe asked for the stage's own thread
