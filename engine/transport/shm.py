"""Large payloads to the other vgr processes of this host through zenoh's shared memory.

zenoh 1.10 (``zenoh.shm``, unstable API) lets a publisher put a buffer it allocated from a
:class:`zenoh.shm.ShmProvider` (a POSIX shared-memory segment, ``/dev/shm/*.zenoh``): a subscriber on
the same host that can map the segment gets a reference to the buffer instead of the bytes, so a
1.2 MB point cloud crosses without the socket's copies and fragmentation. One that cannot (another
host, or shared memory disabled in its session) gets the bytes through the network: zenoh copies
the buffer into the message for that link. The same recipe therefore works on one host, across
hosts and in replay (recordings hold the encoded payload, never a buffer: engine.recording.recorder sees the
bytes before they are put).

What vgr does (engine.transport.wire.WireSender, for the internal ``_wire`` key only):

* a payload of at least :data:`SHM_MIN_BYTES` is copied once into a buffer of the process's pool
  (:class:`ShmPool`, :data:`POOL_BYTES`, made on the first such payload) and put from there;
* a message whose bulk field is ``bytes`` (a Blob, an image's pixels) and whose encoded bytes
  nobody else needs (no recorder, no foreign subscriber on the port's public key) is written into
  that buffer in its two parts (engine.messages.codec.encode_parts: the protobuf head, then the bulk), not
  joined into one ``bytes`` first: one copy of the bulk instead of two. A bulk that is an array
  (point clouds) is joined first: zenoh-python's ``ZShmMut`` takes only ``bytes`` or ``bytearray``,
  so an array would need its own copy into one anyway;
* smaller payloads, and batches of small messages (at most engine.transport.wire.BATCH_BYTES, below the
  threshold), go through the socket as before;
* the pool still full after :data:`POOL_WAIT_S` (receivers that hold many buffers in a burst) or no
  shared memory on this host (no ``/dev/shm``): the payload goes as bytes, as it would without
  shared memory. A paced stream never finds the pool full; nothing waits longer than that.

zenoh's own *transport optimisation* (``transport/shared_memory/transport_optimization``: copy any
message above its threshold into an implicit pool, 3072 bytes by default) is kept, with its
threshold raised to :data:`SHM_MIN_BYTES`: below it the socket was as fast or faster.

Why 64 KiB (``python benchmarks/shm_threshold.py``: one-way p50 between two processes over a unix
socket, three alternated runs each, on the shared 2-core VM, so noisy; results/shm_threshold.json):
16 KiB socket 148-223 us, shm 167-195 us; 32 KiB socket 232-267, shm 238-261; 64 KiB socket
235-311, shm 258-325; 128 KiB socket 259-384, shm 194-356; 1.2 MB socket 965-2104, shm 429-492.
Below 64 KiB the socket is as fast or faster, at 64 KiB the two are within the noise, above it
shared memory wins (2-4x at 1.2 MB). Batches of small messages (at most engine.transport.wire.BATCH_BYTES,
60 KiB) stay on the socket.

This is the route of a large payload when the port's consumers are not all on this host (or its
pool of views is full): engine.transport.shm_views, which hands a consumer of this host a read-only
view of the sender's own memory with no copy on receive, comes first (engine.transport.wire). The
receiving side (engine.run.remote_input) reads a payload of zenoh's shared memory with
``ZBytes.to_bytes()`` like any other: zenoh-python 1.10.2's ``ZBytes`` and ``ZShm`` expose no Python
buffer protocol (``ZShm`` has ``is_valid`` only; asked for upstream in eclipse-zenoh/zenoh-python
issue 730), so one copy out of the segment is the least a Python reader can do here (65-85 us for
1.2 MB); the codec then decodes the bulk array as a numpy view of those bytes.

A recipe turns it off with ``zenoh: {shared_memory: false}`` (zenoh's
``transport/shared_memory/enabled``): every payload then travels through the socket.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Any

import zenoh
import zenoh.shm

SHM_MIN_BYTES = 64 * 1024  # payloads from this size go through shared memory (see the docstring)
POOL_BYTES = 32 * 1024 * 1024  # one process's pool: ~26 point clouds of 1.2 MB in flight
POOL_WAIT_S = 0.002  # a full pool is waited for this long (a 1.2 MB payload's time through the socket)
POOL_RETRY_S = 0.0001


def session_entries(enabled: bool) -> dict[str, Any]:
    """zenoh configuration entries (path -> value) for a session with shared memory on or off."""
    if not enabled:
        return {"transport/shared_memory/enabled": False}
    return {
        "transport/shared_memory/enabled": True,
        "transport/shared_memory/transport_optimization/message_size_threshold": SHM_MIN_BYTES,
    }


class ShmPool:
    """One process's shared-memory pool, made on first use; :meth:`wrap` turns a large payload
    into a zenoh buffer of the pool (or leaves it as it is)."""

    def __init__(self, size: int = POOL_BYTES, min_bytes: int = SHM_MIN_BYTES) -> None:
        self.size = size
        self.min_bytes = min_bytes
        self._provider: Any = None
        self._failed = False  # no shared memory on this host: never try again
        self._lock = threading.Lock()
        self.shared = 0  # payloads put from the pool
        self.fallbacks = 0  # large payloads sent as bytes (pool full or unavailable)

    def _get_provider(self) -> Any:
        with self._lock:
            if self._provider is None and not self._failed:
                try:
                    self._provider = zenoh.shm.ShmProvider.default_backend(self.size)
                except Exception:  # no /dev/shm, a limit on segments: bytes it is
                    self._failed = True
            return self._provider

    def wrap(self, payload: bytes | zenoh.ZBytes) -> bytes | zenoh.ZBytes:
        """*payload* in a shared-memory buffer when it is large and the pool has room, else itself
        (a payload :meth:`wrap_parts` already put in the pool passes through)."""
        n = len(payload)
        if n < self.min_bytes or type(payload) is not bytes:
            return payload
        buf = self._alloc(n)
        if buf is None:
            return payload
        buf[0:n] = payload
        return zenoh.ZBytes(buf)

    def wrap_parts(self, head: bytes, bulk: bytes | memoryview) -> bytes | bytearray | zenoh.ZBytes:
        """``head + bulk`` (engine.messages.codec.encode_parts) written straight into a shared-memory buffer
        when it is large, *bulk* is ``bytes`` (what ``ZShmMut`` takes) and the pool has room, else
        joined: one copy of the bulk either way. A payload the pool had no room for comes back as a
        ``bytearray``, which :meth:`wrap` passes through (tried once)."""
        h, n = len(head), len(head) + len(bulk)
        if n < self.min_bytes or type(bulk) is not bytes:
            return b"".join((head, bulk))  # (an array's bytes: WireSender's wrap puts them in the pool)
        buf = self._alloc(n)
        if buf is None:
            return bytearray().join((head, bulk))
        buf[0:h] = head
        buf[h:n] = bulk
        return zenoh.ZBytes(buf)

    def _alloc(self, n: int) -> Any:
        """A buffer of *n* bytes from the pool (counted in ``shared``), None when there is no pool or
        still no room in it after :data:`POOL_WAIT_S` (counted in ``fallbacks``).

        The buffers receivers have released are collected before each allocation, so the one just
        freed is used again while its pages are mapped and in cache (1.2 MB: 78-82 us to allocate
        and fill against 111-128 us when the allocator moves on through the pool). A full pool
        (receivers that hold many buffers: a burst) is waited for a little, as long as sending the
        payload through the socket would take, rather than given up on at once."""
        provider = self._provider or self._get_provider()
        if provider is None:
            self.fallbacks += 1
            return None
        deadline = 0.0
        while True:
            provider.garbage_collect()
            try:
                buf = provider.alloc(n, _JUST_ALLOC)
                break
            except zenoh.ZError:  # no room: receivers still hold the pool's buffers
                now = time.monotonic()
                if not deadline:
                    deadline = now + POOL_WAIT_S
                elif now >= deadline:
                    self.fallbacks += 1
                    return None
                time.sleep(POOL_RETRY_S)
        self.shared += 1
        return buf

    def close(self) -> None:
        with self._lock, contextlib.suppress(Exception):
            self._provider = None


_JUST_ALLOC = zenoh.shm.JustAlloc()  # (the collection is done just before, see ShmPool._alloc)
