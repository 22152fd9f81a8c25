"""Loaned arrays (engine.transport.shm_views.ViewPool.loan, ``ctx.loan``): a stage fills an array
that already lives in its port's pool and the message goes out without a copy; the block stays
the sender's while the stage's array lives, and a recorder's view holds it too.

Sender and receiver are in this process, as in tests/engine_core/test_shm_views.py (a pool's memfd
opens through ``/proc/<pid>/fd`` from here as from another process).
"""

from __future__ import annotations

import gc

import numpy as np
import pytest

from engine.messages import PointCloud, codec
from engine.transport.shm_views import LOAN_HEAD_BYTES, ViewPayload, ViewPool, ViewReader

pytestmark = pytest.mark.timeout(120)

POINTS = 50_000  # 1.2 MB of float64 points


class Peers:
    """Stands for HostPeers: the consumer process maps this host's memory, with one session."""

    def __init__(self, processes: list[str]) -> None:
        self.sessions = {p: frozenset({f"zid-{p}"}) for p in processes}

    def zids(self, process: str) -> frozenset[str]:
        return self.sessions.get(process, frozenset())


def pool_and_reader() -> tuple[ViewPool, ViewReader]:
    return ViewPool(Peers(["b"]), [("b", "sink", "cloud")], size=16 * POINTS * 24), ViewReader(0)  # type: ignore[arg-type]


def loaned_cloud(pool: ViewPool, k: int) -> tuple[np.ndarray, PointCloud]:
    buf = pool.loan(POINTS * 3 * 8)
    assert buf is not None and buf.flags.writeable
    points = buf.view(np.float64).reshape(POINTS, 3)
    points[:] = np.arange(POINTS * 3, dtype=np.float64).reshape(POINTS, 3) + k
    return buf, PointCloud(points=points, frame_id="camera")


def received(
    pool: ViewPool, reader: ViewReader, msg: PointCloud, *, hold: bool = False
) -> tuple[ViewPayload, PointCloud]:
    placed = pool.place(*codec.encode_parts(msg), hold=hold)
    assert isinstance(placed, ViewPayload)
    return placed, codec.decode_payload(PointCloud, reader.payload(placed.descriptor))  # type: ignore[return-value]


def test_a_loaned_cloud_goes_out_without_a_copy_and_arrives_whole():
    pool, reader = pool_and_reader()
    buf, msg = loaned_cloud(pool, 0)
    placed, got = received(pool, reader, msg)
    assert pool.loaned_sent == 1 and pool.shared == 1  # the stage's own memory was sent
    np.testing.assert_array_equal(got.points, msg.points)
    assert got.frame_id == "camera" and not got.points.flags.writeable
    assert placed.length == len(codec.encode_parts(msg)[0]) + buf.nbytes


def test_the_block_is_the_senders_while_its_array_lives_and_comes_back_after_both_ends_let_go():
    pool, reader = pool_and_reader()
    buf, msg = loaned_cloud(pool, 1)
    _, got = received(pool, reader, msg)
    del got
    gc.collect()
    assert pool.in_flight() == 1  # the consumer released it, but the stage still holds its array
    for k in range(2, 12):  # later payloads never land on it
        _, other = received(pool, reader, loaned_cloud(pool, k)[1])
        assert other.points[0, 0] == k
        del other
    assert msg.points[0, 0] == 1.0 and buf.view(np.float64)[-1] == POINTS * 3 - 1 + 1
    del buf, msg
    gc.collect()
    assert pool.in_flight() == 0


def test_a_loan_never_published_comes_back_when_dropped():
    pool, _ = pool_and_reader()
    bufs = [pool.loan(1 << 20) for _ in range(5)]
    assert all(b is not None for b in bufs) and pool.in_flight() == 5
    del bufs
    gc.collect()
    assert pool.in_flight() == 0


def test_a_loan_published_twice_is_copied_the_second_time_and_both_arrive_whole():
    pool, reader = pool_and_reader()
    _, msg = loaned_cloud(pool, 3)
    _, first = received(pool, reader, msg)
    _, second = received(pool, reader, PointCloud(points=msg.points, frame_id="again"))
    assert pool.loaned_sent == 1 and pool.shared == 2
    np.testing.assert_array_equal(first.points, second.points)
    assert second.frame_id == "again"


def test_a_part_of_a_loan_and_a_head_too_large_for_its_room_are_copied():
    pool, reader = pool_and_reader()
    _buf, msg = loaned_cloud(pool, 4)
    _, part = received(pool, reader, PointCloud(points=msg.points[1:], frame_id="part"))
    long_name = "f" * (2 * LOAN_HEAD_BYTES)
    _, long_head = received(pool, reader, PointCloud(points=msg.points, frame_id=long_name))
    assert pool.loaned_sent == 0 and pool.shared == 2
    np.testing.assert_array_equal(part.points, msg.points[1:])
    assert long_head.frame_id == long_name
    np.testing.assert_array_equal(long_head.points, msg.points)


def test_a_recorders_view_holds_the_block_until_it_is_written():
    pool, reader = pool_and_reader()
    buf, msg = loaned_cloud(pool, 5)
    placed, got = received(pool, reader, msg, hold=True)
    assert placed.view is not None and placed.view.readonly
    expect = b"".join(codec.encode_parts(msg)[0:1]) + buf.tobytes()
    assert bytes(placed.view) == expect  # what the recorder writes: the message's encoded bytes
    view = placed.view
    del buf, msg, got, placed
    gc.collect()
    assert pool.in_flight() == 1  # the recorder has not written it yet
    del view
    gc.collect()
    assert pool.in_flight() == 0


def test_no_loan_where_views_are_not_the_route():
    elsewhere = ViewPool(Peers([]), [("b", "sink", "cloud")])  # type: ignore[arg-type]
    assert elsewhere.loan(1 << 20) is None  # the consumer maps no memory of this host
    pool, _ = pool_and_reader()
    assert pool.loan(100) is None  # too small to be worth a block
