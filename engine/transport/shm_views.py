"""Large payloads to the stages of other vgr processes on this host as read-only numpy views of
shared memory that vgr owns: one pool per output port (a ``memfd``), a small descriptor over zenoh.

Why this route (``python benchmarks/shm_view.py``, results/shm_view.json: one-way p50 of 1.2 MB
between two processes over tcp/127.0.0.1, paced 5 ms, four alternated runs on the shared 2-core VM):

* zenoh's shared memory, copied out on receive (``ZBytes.to_bytes()``; zenoh-python 1.10.2's
  ``ZBytes``/``ZShm`` still expose no buffer protocol, only ``is_valid``): 471-572 us, median 545;
* iceoryx2 0.10 (pip ``iceoryx2``), a sample loaned, filled and sent, a zenoh descriptor to wake the
  receiver and keep the order with the port's small messages, a view of the sample on receive:
  219-356 us, median 294;
* this module (a memfd block filled, a 64-byte descriptor over zenoh, a view on receive):
  182-265 us, median 225.

The pool vgr owns is the fastest and needs no new dependency, and it has the properties the
others would need glue for: the order with the port's other messages is zenoh's (the descriptor is
one sample of the stream), a ``memfd`` has no name, so a process killed at any moment leaves
nothing behind (the kernel frees the memory when the last process that maps it ends; iceoryx2
leaves files under ``/dev/shm`` and ``/tmp/iceoryx2`` until a live node cleans up after a dead one),
and a view's lifetime is Python's own reference count (below). Over a million messages of 77 kB
(``benchmarks/shm_view.py --leak 1000000``, results/shm_view_leak.json) nothing leaked: the same
file descriptors and mappings before and after, no block in flight, 29 us per message placed,
viewed and released on the loaded 2-core VM.

How it goes:

* the sender (:class:`ViewPool`, made on the port's first large payload) writes the encoded payload
  into a free block of its pool (first fit: the block just released, still in cache, is used again)
  and puts a descriptor (:data:`DESC`: its pid and the memfd's descriptor number, the pool's random
  nonce, block, generation, offset, length) with the message's envelope, kind ``VIEW``;
* the receiver (:class:`ViewReader`) maps the pool once (``/proc/<pid>/fd/<fd>``: the header
  read-write, the data read-only), checks the nonce (a reused pid is not taken for the sender) and
  hands the codec a view of the block, which decodes the bulk array as a numpy view of it: no copy;
* a stage may instead fill an array the pool lends it (:meth:`ViewPool.loan`, ``ctx.loan`` in
  docs/writing_stages.md): a message whose bulk array is that loan is sent with its head written
  into the :data:`LOAN_HEAD_BYTES` left before the array, so the payload is never copied on the
  sender either; the block stays the sender's while the stage's array lives (a holder token,
  taken out by the array's finalizer) and goes back once that and every consumer's view are gone.
  A recorded port hands its recorder a held view of the placed block, not a joined copy;
* the block is released when the last Python object that refers to it goes (a ``weakref.finalize``
  on the view's base array): the receiver writes the block's generation into its release word in
  the pool's header, and the sender takes the block back once every consumer of the block did.

**The lifetime rule** (docs/writing_stages.md): a received array may be a read-only view of the
sender's memory. It stays valid for as long as anything refers to it, however long that is; it is
never overwritten under a reader (the block goes back to the sender only when the last reference
goes), and writing into it raises ``ValueError: assignment destination is read-only``. A stage that
keeps a message past its handler keeps its block: a few (a reference cloud, the last one) are fine;
one that keeps many should copy what it keeps (``np.array(msg.points)``), or the sender's pool
fills, after which the sender sends bytes (zenoh's route, one copy on receive) until blocks come
back. Nothing waits longer than :data:`POOL_WAIT_S` for a block.

Who gets views: a process that can map this host's memory declares the liveliness token
``vgr/<run>/_shmhost/<process>/<host>/<zid>`` (:class:`HostPeers`; ``<host>`` is :func:`host_key`: the
boot, the pid and network namespaces, the user). A port sends views only while every process that
consumes it holds a token of the sender's host; otherwise (a consumer on another host, in another
network namespace or container, or with ``zenoh: {shared_memory: false}``) the payload goes the way
engine.transport.shm says, which zenoh turns into bytes on the network for another host. A
consumer whose token goes (it ended or was killed) is no longer waited for: its blocks come back.
Recordings hold the encoded payload either way (the recorder is handed the view's bytes), so a
replay is the same whatever route a message took.
"""

from __future__ import annotations

import contextlib
import hashlib
import mmap
import os
import secrets
import struct
import threading
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from engine.messages.codec import CodecError, Kind

VIEW_MIN_BYTES = 64 * 1024  # payloads from this size go as views (engine.transport.shm's threshold)
POOL_BYTES = 32 * 1024 * 1024  # a port's pool (at least 8 of its first payload): ~26 clouds of 1.2 MB
MAX_BLOCKS = 64  # blocks in flight per pool
MAX_CONSUMERS = 16  # consumer inputs of one port in other processes that views can serve
POOL_WAIT_S = 0.002  # a full pool is waited for this long (a 1.2 MB payload's time through the socket)
POOL_RETRY_S = 0.0001
ALIGN = 64
LOAN_HEAD_BYTES = 1024  # room before a loaned array for the message's other fields (its protobuf head)
MAGIC = b"VGRPOOL1"
TABLE_OFFSET = 4096  # release words: MAX_BLOCKS x MAX_CONSUMERS u64, written by the receivers
HEADER_BYTES = TABLE_OFFSET + MAX_BLOCKS * MAX_CONSUMERS * 8  # (a multiple of the page size)
_TOP = struct.Struct("<8s16sQ")  # magic, nonce, data bytes
DESC = struct.Struct("<4sii16sIQQQ")  # b"VGRV", pid, fd, nonce, block, generation, offset, length
DESC_MAGIC = b"VGRV"
VIEW_KIND = bytes((Kind.VIEW,))


def host_key() -> str:
    """This host as shared memory sees it: processes with the same key can map each other's pools
    (one boot of one machine, one pid and one network namespace, one user)."""
    parts = [str(os.getuid())]
    with contextlib.suppress(OSError):
        parts.append(open("/proc/sys/kernel/random/boot_id").read().strip())  # noqa: SIM115
    for ns in ("pid", "net"):
        with contextlib.suppress(OSError):
            parts.append(str(os.stat(f"/proc/self/ns/{ns}").st_ino))
    return hashlib.sha256("/".join(parts).encode()).hexdigest()[:16]


def view_envelope(envelope: bytes) -> bytes:
    """The envelope of a descriptor sample: the message's own, kind VIEW instead of DATA."""
    return envelope[:4] + VIEW_KIND + envelope[5:]


def data_envelope_of(view_env: bytes) -> bytes:
    """The message's own DATA envelope back from a descriptor's (what observers are shown)."""
    return view_env[:4] + b"\x00" + view_env[5:]


def host_token_key(run: str, process: str, host: str, zid: str) -> str:
    return f"vgr/{run}/_shmhost/{process}/{host}/{zid}"


class HostPeers:
    """Which processes of a run can map this host's pools: this process's token (declared when
    *declare*), and the tokens of the others, kept up to date by a liveliness subscriber."""

    def __init__(self, session: zenoh.Session, run: str, process: str, zid: str, *, declare: bool) -> None:
        self.host = host_key()
        self._present: dict[str, set[str]] = {}  # process -> zids holding a token of this host
        self._lock = threading.Lock()
        self._token: Any = None
        self._sub = session.liveliness().declare_subscriber(
            f"vgr/{run}/_shmhost/**", zenoh.handlers.Callback(self._on_sample, indirect=True), history=True
        )
        if declare:
            self._token = session.liveliness().declare_token(host_token_key(run, process, self.host, zid))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) != 6 or parts[4] != self.host:
            return
        process, zid = parts[3], parts[5]
        with self._lock:
            zids = self._present.setdefault(process, set())
            if sample.kind == zenoh.SampleKind.DELETE:
                zids.discard(zid)
            else:
                zids.add(zid)

    def zids(self, process: str) -> frozenset[str]:
        """The sessions of *process* that map this host's pools now (empty: none)."""
        with self._lock:
            return frozenset(self._present.get(process, ()))

    def withdraw(self) -> None:
        """This process cannot map a pool after all: its token goes, senders send bytes."""
        if self._token is not None:
            with contextlib.suppress(Exception):
                self._token.undeclare()
            self._token = None

    def close(self) -> None:
        self.withdraw()
        with contextlib.suppress(Exception):
            self._sub.undeclare()


@dataclass(frozen=True, slots=True)
class ViewPayload:
    """A payload written into a block of a pool: what goes on zenoh is :attr:`descriptor`; with
    ``hold``, :attr:`view` is a read-only view of the bytes that keeps the block while it lives (what
    the port's recorder is handed)."""

    descriptor: bytes
    length: int
    view: memoryview | None = None

    def __len__(self) -> int:
        return self.length


@dataclass(slots=True)
class _Block:
    offset: int
    end: int
    generation: int
    waits_for: tuple[tuple[int, str, frozenset[str]], ...]  # (release word, process, its sessions then)
    loaned: bool = False  # handed to the stage by :meth:`ViewPool.loan` (its data from LOAN_HEAD_BYTES on)
    sent: bool = False  # its descriptor went out (the consumers' releases count from then on)
    # arrays of it alive in this process (the stage's loaned one, the view a recorder was handed):
    # one token each, taken out by the array's finalizer (set.discard: atomic, no lock needed)
    holders: set[object] = field(default_factory=set)


class ViewPool:
    """One output port's pool (see the module docstring): *consumers* are the (process, stage,
    port) of its inputs in other processes, in :func:`consumer_order`."""

    def __init__(self, peers: HostPeers, consumers: Sequence[tuple[str, str, str]], size: int = POOL_BYTES) -> None:
        self.peers = peers
        self.consumers = list(consumers)
        self.processes = sorted({c[0] for c in self.consumers})
        self.size = size
        self.usable = 0 < len(self.consumers) <= MAX_CONSUMERS
        self._fd = -1
        self._data: memoryview | None = None
        self._table: np.ndarray | None = None
        self._map: mmap.mmap | None = None
        self._nonce = secrets.token_bytes(16)
        self._blocks: dict[int, _Block] = {}  # block index -> block in flight
        self._free = list(range(MAX_BLOCKS - 1, -1, -1))
        self._generation = 0
        self._lock = threading.Lock()
        self._loans: dict[int, tuple[int, int]] = {}  # id of a loaned array not sent yet -> (block, bytes)
        self.shared = 0  # payloads sent as views
        self.loaned_sent = 0  # ... of them, loaned arrays sent without a copy
        self.fallbacks = 0  # large payloads that found the pool full (sent the other way)

    def all_here(self) -> bool:
        """Every consumer process maps this host's pools now."""
        zids = self.peers.zids
        return self.usable and all(zids(p) for p in self.processes)

    def place(
        self, head: bytes | bytearray | memoryview, bulk: bytes | memoryview | None = None, *, hold: bool = False
    ) -> ViewPayload | None:
        """``head + bulk`` written into a block (no copy when *bulk* is a loaned array: :meth:`loan`),
        or None: small, a consumer that cannot map this host's memory, no memfd here, or the pool still
        full after :data:`POOL_WAIT_S`. *hold*: the payload's :attr:`ViewPayload.view` too."""
        n = len(head) + (len(bulk) if bulk is not None else 0)
        if n < VIEW_MIN_BYTES or not self.all_here():
            return None
        with self._lock:
            if self._data is None and not self._open(n):
                return None
            placed = self._send_loaned(head, bulk) if bulk is not None and self._loans else None
            if placed is None:
                got = self._alloc(n)
                if got is None:
                    self.fallbacks += 1
                    return None
                index, block = got
                data = self._data
                assert data is not None
                h = len(head)
                data[block.offset : block.offset + h] = head
                if bulk is not None:
                    data[block.offset + h : block.offset + n] = memoryview(bulk).cast("B")
                self.shared += 1
                placed = index, block.offset
            index, start = placed
            desc = DESC.pack(
                DESC_MAGIC, os.getpid(), self._fd, self._nonce, index, self._blocks[index].generation, start, n
            )
            return ViewPayload(desc, n, memoryview(self._held(index, start, n, writeable=False)) if hold else None)

    def loan(self, nbytes: int) -> np.ndarray | None:
        """A writable uint8 array of *nbytes* in a block of the pool, for the stage to fill and
        publish (a message whose bulk field is this array goes out without a copy: its head is
        written into the :data:`LOAN_HEAD_BYTES` before it); None when views are not the route now
        (small, a consumer elsewhere, no memfd, the pool full). The block is taken back once the
        array is gone here and every consumer released what was sent; it is sent as a view once
        (published again, it is copied like any payload)."""
        if nbytes + LOAN_HEAD_BYTES < VIEW_MIN_BYTES or not self.all_here():
            return None
        with self._lock:
            if self._data is None and not self._open(nbytes + LOAN_HEAD_BYTES):
                return None
            got = self._alloc(nbytes + LOAN_HEAD_BYTES)
            if got is None:
                self.fallbacks += 1
                return None
            index, block = got
            block.loaned = True
            array = self._held(index, block.offset + LOAN_HEAD_BYTES, nbytes, writeable=True)
            self._loans[id(array)] = (index, nbytes)
            weakref.finalize(array, self._loans.pop, id(array), None)  # (an id is reused once its object is gone)
            return array

    def _held(self, index: int, start: int, n: int, *, writeable: bool) -> np.ndarray:
        """An array of *n* bytes of block *index* from *start* that keeps the block while it lives."""
        assert self._data is not None
        array = np.frombuffer(self._data, dtype=np.uint8, count=n, offset=start)
        if not writeable:
            array.flags.writeable = False
        token = object()
        holders = self._blocks[index].holders
        holders.add(token)
        weakref.finalize(array, holders.discard, token)  # (may run on any thread, inside our lock: none taken)
        return array

    def _send_loaned(self, head: bytes | bytearray | memoryview, bulk: bytes | memoryview) -> tuple[int, int] | None:
        """(block, start) of the payload when *bulk* is the whole of a loaned array not sent yet (found
        by identity along its chain of bases: the message's array may be a view of the loan), its
        *head* then written just before it; None otherwise (or when the head does not fit)."""
        loans, obj, found = self._loans, getattr(bulk, "obj", None), None
        for _ in range(8):  # (memoryview -> the message's array -> ... -> the loaned array)
            if obj is None:
                break
            found = loans.get(id(obj))
            if found is not None:
                break
            obj = obj.obj if isinstance(obj, memoryview) else getattr(obj, "base", None)
        if found is None:
            return None
        index, nbytes = found
        block, h = self._blocks.get(index), len(head)
        if block is None or block.sent or h > LOAN_HEAD_BYTES or len(bulk) != nbytes:  # (a part of it: copied)
            return None
        del loans[id(obj)]
        start = block.offset + LOAN_HEAD_BYTES
        assert self._data is not None
        self._data[start - h : start] = head
        block.sent = True
        self.shared += 1
        self.loaned_sent += 1
        return index, start - h

    def _open(self, first: int) -> bool:
        self.size = max(self.size, 8 * first)
        self.size += -self.size % mmap.PAGESIZE
        try:
            fd = os.memfd_create("vgr-views", os.MFD_CLOEXEC)
            os.ftruncate(fd, HEADER_BYTES + self.size)
            whole = mmap.mmap(fd, HEADER_BYTES + self.size)
        except (OSError, AttributeError):  # no memfd here: the other route
            self.usable = False
            return False
        whole[: _TOP.size] = _TOP.pack(MAGIC, self._nonce, self.size)
        self._fd, self._map = fd, whole
        view = memoryview(whole)
        self._table = np.frombuffer(whole, dtype=np.uint64, count=MAX_BLOCKS * MAX_CONSUMERS, offset=TABLE_OFFSET)
        self._data = view[HEADER_BYTES:]
        return True

    def _alloc(self, n: int) -> tuple[int, _Block] | None:
        """A free block of *n* bytes (the blocks released are taken back first), waiting up to
        :data:`POOL_WAIT_S` when there is none."""
        deadline = 0.0
        while True:
            self._reclaim()
            got = self._fit(n)
            if got is not None:
                return got
            now = time.monotonic()
            if not deadline:
                deadline = now + POOL_WAIT_S
            elif now >= deadline:
                return None
            time.sleep(POOL_RETRY_S)

    def _reclaim(self) -> None:
        table = self._table
        assert table is not None
        zids = self.peers.zids
        for index, block in list(self._blocks.items()):
            if block.holders:  # an array of it is still alive here (a loaned one, a recorder's view)
                continue
            if (block.loaned and not block.sent) or all(
                table[word] == block.generation or not (zids(p) & then) for word, p, then in block.waits_for
            ):
                del self._blocks[index]
                self._free.append(index)

    def _fit(self, n: int) -> tuple[int, _Block] | None:
        if not self._free:
            return None
        size = n + (-n % ALIGN)
        start = 0
        for block in sorted(self._blocks.values(), key=lambda b: b.offset):
            if block.offset - start >= size:
                break
            start = block.end
        if start + size > self.size:
            return None
        index = self._free.pop()
        self._generation += 1
        waits = tuple(
            (index * MAX_CONSUMERS + k, proc, self.peers.zids(proc)) for k, (proc, _, _) in enumerate(self.consumers)
        )
        block = self._blocks[index] = _Block(start, start + size, self._generation, waits)
        return index, block

    def in_flight(self) -> int:
        """Blocks not yet taken back (after taking back what was released)."""
        with self._lock:
            if self._table is not None:
                self._reclaim()
            return len(self._blocks)

    def close(self) -> None:
        """Drop this process's hold on the pool (consumers' views keep their mapping)."""
        with self._lock:
            self._data = self._table = None
            if self._map is not None:
                with contextlib.suppress(BufferError):
                    self._map.close()
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1


def consumer_order(edges: Sequence[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    """The (process, stage, port) of a port's consumers in other processes, in the order both ends
    number them (the index of an input is its release word in every block)."""
    return sorted(set(edges))


class _Mapping:
    """One sender's pool as a receiver maps it: the data read-only, the release words writable."""

    def __init__(self, pid: int, fd: int, nonce: bytes) -> None:
        try:
            f = os.open(f"/proc/{pid}/fd/{fd}", os.O_RDWR)
        except OSError as exc:
            raise CodecError(f"cannot open the sender's shared memory (pid {pid}): {exc}") from None
        try:
            header = mmap.mmap(f, HEADER_BYTES)
            magic, got_nonce, size = _TOP.unpack_from(header)
            if magic != MAGIC or got_nonce != nonce:
                header.close()
                raise CodecError(f"pid {pid}'s descriptor {fd} is not the sender's pool (it ended?)")
            self.data = mmap.mmap(f, size, offset=HEADER_BYTES, prot=mmap.PROT_READ)
        finally:
            os.close(f)
        self.size = size
        self.table = np.frombuffer(header, dtype=np.uint64, count=MAX_BLOCKS * MAX_CONSUMERS, offset=TABLE_OFFSET)


def _release(table: np.ndarray, word: int, generation: int) -> None:
    table[word] = generation


class ViewReader:
    """The receiving end of one input: a descriptor in, a read-only view of the block out, released
    when the last reference to it goes. Consumer number *index* (:func:`consumer_order`)."""

    def __init__(self, index: int) -> None:
        self.index = index
        self._maps: dict[tuple[int, int, bytes], _Mapping] = {}
        self.views = 0  # descriptors resolved

    def payload(self, descriptor: bytes | memoryview) -> memoryview:
        """A read-only view of the payload *descriptor* names (CodecError when it cannot be had)."""
        try:
            magic, pid, fd, nonce, block, generation, offset, length = DESC.unpack(descriptor)
        except struct.error:
            raise CodecError(f"not a shared-memory descriptor ({len(descriptor)} bytes)") from None
        if magic != DESC_MAGIC or not 0 <= block < MAX_BLOCKS:
            raise CodecError("not a shared-memory descriptor")
        key = (pid, fd, nonce)
        m = self._maps.get(key)
        if m is None:
            m = self._maps[key] = _Mapping(pid, fd, nonce)
        if offset + length > m.size:
            raise CodecError(f"descriptor past the end of the pool ({offset}+{length} > {m.size})")
        base = np.frombuffer(m.data, dtype=np.uint8, count=length, offset=offset)  # read-only, no copy
        weakref.finalize(base, _release, m.table, block * MAX_CONSUMERS + self.index, generation)
        self.views += 1
        return memoryview(base)  # type: ignore[arg-type]  # (an ndarray is a buffer)

    def close(self) -> None:
        """Forget the mappings (the views still held keep theirs until they go)."""
        self._maps.clear()
