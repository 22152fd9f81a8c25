"""Large payloads between processes of one host through zenoh's shared memory (engine.transport.shm).

Two OS processes over a unix socket, as vgr's default session puts the processes of one host:
the child (tests/engine_core/shm_child.py) sends through engine.transport.wire.WireSender with its bus's
pool, this process receives with engine.transport.bus.Bus.subscribe_remote, as engine.run.remote_input does. A
large payload arrives as a shared-memory buffer, a small one (and a large one when either side has
shared memory off) as bytes over the socket; the data are the same in every case.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from process_helpers import env
from shm_child import payload

from engine.recipe.model import ZenohSettings
from engine.transport.bus import Bus
from engine.transport.shm import SHM_MIN_BYTES, ShmPool

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]

CHILD = Path(__file__).with_name("shm_child.py")
KEY = "vgr/shm_t/_wire/src/out"
LARGE, SMALL = 1_200_000, 4096


def exchange(sizes: list[int], *, child_shm: bool = True, parent_shm: bool = True) -> tuple[list[dict], dict]:
    """Run the child sending *sizes*; what arrived here (per sample: shm or not, bytes, attachment)
    and the child's pool counters."""
    folder = Path(tempfile.mkdtemp(prefix="vgr-shm-"))  # short: a unix socket path has ~100 bytes
    endpoint = f"unixsock-stream/{folder / 'p.sock'}"
    bus = Bus(ZenohSettings(listen=[endpoint], shared_memory=parent_shm))
    try:
        _, channel = bus.subscribe_remote(KEY)
        child = subprocess.Popen(
            [sys.executable, str(CHILD), endpoint, KEY, "1" if child_shm else "0", *map(str, sizes)],
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        got: list[dict] = []
        deadline = time.monotonic() + 60  # a bound on a broken run, not a measured time
        while len(got) < len(sizes) and time.monotonic() < deadline:
            sample = channel.try_recv()
            if sample is None:
                time.sleep(0.005)
                continue
            got.append(
                {
                    "shm": sample.payload.as_shm() is not None,
                    "data": sample.payload.to_bytes(),
                    "att": sample.attachment.to_bytes(),
                }
            )
        out, err = child.communicate(timeout=60)
        assert child.returncode == 0, err
        return got, json.loads(out)
    finally:
        bus.close()
        shutil.rmtree(folder, ignore_errors=True)


def test_a_large_payload_goes_through_shared_memory_a_small_one_through_the_socket():
    sizes = [LARGE, SMALL, SHM_MIN_BYTES, SHM_MIN_BYTES - 1, LARGE]
    got, pool = exchange(sizes)
    assert [g["shm"] for g in got] == [True, False, True, False, True]
    assert [g["data"] for g in got] == [payload(k, n) for k, n in enumerate(sizes)]  # identical, in order
    assert [g["att"] for g in got] == [b"env%d" % k for k in range(len(sizes))]
    assert pool == {"shared": 3, "fallbacks": 0}


@pytest.mark.parametrize("side", ["receiver", "sender"])
def test_shared_memory_off_on_one_side_falls_back_to_the_socket(side):
    sizes = [LARGE, SMALL, LARGE]
    got, _ = exchange(sizes, child_shm=side != "sender", parent_shm=side != "receiver")
    assert [g["shm"] for g in got] == [False, False, False]
    assert [g["data"] for g in got] == [payload(k, n) for k, n in enumerate(sizes)]


def test_a_full_pool_sends_bytes_after_a_short_wait():
    pool = ShmPool(size=2 * LARGE, min_bytes=SHM_MIN_BYTES)
    held = [pool.wrap(payload(k, LARGE)) for k in range(4)]  # nobody releases them
    assert [type(h) for h in held[:1]] == [zenoh.ZBytes]
    assert isinstance(held[-1], bytes) and held[-1] == payload(3, LARGE)
    assert pool.fallbacks >= 1 and pool.shared + pool.fallbacks == 4


@settings(max_examples=25, deadline=None)
@given(st.integers(min_value=0, max_value=3 * SHM_MIN_BYTES))
def test_wrapping_keeps_the_bytes_and_only_large_payloads_are_shared(n):
    pool = ShmPool(size=4 * SHM_MIN_BYTES)
    data = bytes(range(256)) * (n // 256) + bytes(n % 256)
    wrapped = pool.wrap(data)
    if n < SHM_MIN_BYTES:
        assert wrapped is data
    else:
        assert isinstance(wrapped, zenoh.ZBytes) and wrapped.as_shm() is not None
        assert wrapped.to_bytes() == data


@settings(max_examples=25, deadline=None)
@given(st.binary(max_size=40), st.integers(min_value=0, max_value=2 * SHM_MIN_BYTES))
def test_the_two_parts_of_a_message_land_in_one_buffer_in_order(head, n):
    pool = ShmPool(size=4 * SHM_MIN_BYTES)
    bulk = payload(n % 7, n)
    wrapped = pool.wrap_parts(head, bulk)
    if len(head) + n < SHM_MIN_BYTES:
        assert wrapped == head + bulk and pool.shared == 0
    else:
        assert isinstance(wrapped, zenoh.ZBytes) and wrapped.as_shm() is not None
        assert wrapped.to_bytes() == head + bulk and pool.shared == 1
    assert pool.wrap(wrapped) is wrapped  # already in the pool (or small): put as it is
    as_view = pool.wrap_parts(head, memoryview(bulk))  # an array's bytes: joined, for the wire to place
    assert as_view == head + bulk and type(as_view) is bytes


def test_a_full_pool_joins_the_parts_after_a_short_wait_and_the_wire_does_not_try_again():
    pool = ShmPool(size=2 * LARGE, min_bytes=SHM_MIN_BYTES)
    held = [pool.wrap_parts(b"head%d" % k, payload(k, LARGE)) for k in range(4)]
    assert isinstance(held[0], zenoh.ZBytes)
    assert isinstance(held[-1], bytearray) and held[-1] == b"head3" + payload(3, LARGE)
    assert pool.wrap(held[-1]) is held[-1]  # (WireSender wraps every payload: no second wait)
    assert pool.fallbacks >= 1 and pool.shared + pool.fallbacks == 4


def full_pool(monkeypatch) -> tuple[ShmPool, list]:
    """A pool of three 1.2 MB payloads' size, filled: the buffers it holds (nobody released them)."""
    import engine.transport.shm

    monkeypatch.setattr(engine.transport.shm, "POOL_WAIT_S", 0.0)
    pool = ShmPool(size=3 * LARGE, min_bytes=SHM_MIN_BYTES)
    held = []
    while len(held) < 10 and isinstance(wrapped := pool.wrap(payload(len(held), LARGE)), zenoh.ZBytes):
        held.append(wrapped)
    assert 1 <= len(held) < 10 and pool.fallbacks == 1
    return pool, held


def test_a_buffer_released_is_used_again_rather_than_sending_bytes(monkeypatch):
    pool, held = full_pool(monkeypatch)
    held.pop()  # a receiver is done with one
    again = pool.wrap(payload(50, LARGE))
    assert isinstance(again, zenoh.ZBytes) and again.to_bytes() == payload(50, LARGE)
    assert pool.fallbacks == 1


def test_a_full_pool_is_waited_for_while_a_receiver_releases_a_buffer(monkeypatch):
    import engine.transport.shm

    pool, held = full_pool(monkeypatch)
    monkeypatch.setattr(engine.transport.shm, "POOL_WAIT_S", 30.0)  # a bound on a broken wait, not a measured time
    release = threading.Timer(0.05, held.pop)  # the receiver copies one out a little later
    release.start()
    try:
        waited = pool.wrap_parts(b"head", payload(7, LARGE))
    finally:
        release.join()
    assert isinstance(waited, zenoh.ZBytes) and waited.to_bytes() == b"head" + payload(7, LARGE)
    assert pool.fallbacks == 1  # (the one that found the pool full while filling it)
