"""Stage-to-stage messages between vgr processes of one host over a unix socket vgr owns: the
listener of a producing process, one consumer's link, the frames on it, the consumer's handshake.

Why (``python benchmarks/local_link.py``, results/local_link.json: one-way p50 between two Python
processes, paced 1 ms, five alternated runs on the shared 2-core VM, median [range]): a zenoh put
reaches a subscriber's callback in another process through zenoh's transmit and receive tasks, two
thread wake-ups on vCPUs that were idle: 64 B 173 us [153-181] over tcp/127.0.0.1, 169 [155-172]
over a unix socket; iceoryx2 0.10 (a loaned sample, then an event that wakes the receiver's
listener) 81 [65-94]; a thread blocked in ``recv`` on a unix stream socket, woken by the producer's
own ``sendmsg`` (this module), one wake-up: 49 [40-57]. 4 KiB: 182, 170, 88 and 55 us. A socket
also needs no new dependency, keeps the port's order with no extra step (one stream per consumer),
and leaves nothing behind when a process is killed (iceoryx2 leaves files under ``/dev/shm`` and
``/tmp/iceoryx2`` until a live node cleans up after a dead one).

How it goes:

* a process whose stages feed stages of other processes listens on ``<run folder>/<process>.links``
  (engine.transport.endpoints.private_socket_dir: a folder only the user can open, the trust of
  the private zenoh sockets next to it);
* after every process of the run has joined (so a listener of this host exists by then, and its
  absence means another host), each input fed from another process connects to its producer's
  listener and says which port it wants (:func:`open_link`: JSON naming run, producer stage and
  port, consumer process, stage and input, and :func:`engine.transport.shm_views.host_key`);
* the producer takes the link only while that port has published nothing yet (so every message
  of the port goes over the link, none before it through zenoh) and only from a consumer the graph
  names, on its own host key (another network namespace or container goes through zenoh);
* from then on the port's messages to that consumer are *frames* (``struct "<II"``: envelope
  length, payload length; then the envelope, then the payload: the records of an
  engine.transport.wire batch), written by the publishing thread (or the port's sender thread,
  for a burst) with one ``sendmsg``; the consumer's thread for the link reads them
  (:class:`FrameReader`). Consumers on other hosts, or that did not link, get the port's messages
  through zenoh as before, so one port may feed both.

Nothing waits without bound: a producer's send waits at most :data:`SEND_TIMEOUT_S` for room (the
consumer's reader runs a handler itself only while handlers are quick, and queues otherwise, so
only one very long handler, or a process that stopped running, leaves the socket full), after which
the link is closed with a warning and the consumer gets nothing more, as when zenoh's congestion
control closes a link (after 5 s); a stop closes every link at once (:meth:`LinkSender.close`
needs no lock), so a producer waiting for room wakes. A killed consumer closes its end (the
producer's next send fails and drops the link); a killed producer ends the consumer's reads (a cut
frame is dropped). With a ``security:`` block, or ``zenoh: {local_links: false}``, there are no
links: every message goes through zenoh (its TLS and access control).

Over a million messages through one link (``python benchmarks/local_link.py --leak 1000000``,
results/local_link_leak.json: every 100th a 700 kB payload, the rest 64 B) every frame arrived whole
and in order, with the same open file descriptors and threads before and after and 1.8 MB more
resident memory (the allocator's pools); a link is one socket per consuming input, nothing per message.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import stat
import struct
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from engine.transport.endpoints import private_socket_dir

log = logging.getLogger("vgr.local_link")
FRAME = struct.Struct("<II")  # envelope length, payload length (as a batch record)
_HELLO_LEN = struct.Struct("<I")
HELLO_MAX = 4096  # bytes of a consumer's hello
HANDSHAKE_TIMEOUT_S = 2.0
SEND_TIMEOUT_S = 30.0
ACCEPTED, REFUSED = b"\x01", b"\x00"
RECV_BYTES = 256 * 1024  # one read of a link's frames


def link_path(run: str, process: str) -> Path:
    """The socket *process* of run *run* listens on for links."""
    return private_socket_dir() / run / f"{process}.links"


class LinkSender:
    """The producer's end of one consumer's link: :meth:`send` a frame; False once the link is
    gone (the consumer closed it, or stopped reading for :data:`SEND_TIMEOUT_S`)."""

    def __init__(self, sock: socket.socket, name: str) -> None:
        sock.settimeout(SEND_TIMEOUT_S)
        self.sock = sock
        self.name = name
        self.alive = True
        self._sendmsg = sock.sendmsg
        self._pack = FRAME.pack

    def send(self, envelope: bytes, payload: Any) -> bool:
        parts = [self._pack(len(envelope), len(payload)), envelope, payload]
        total = FRAME.size + len(envelope) + len(payload)
        try:
            sent = self._sendmsg(parts)
            if sent != total:  # (a large payload, or a full socket buffer: the rest in order)
                self._send_rest(parts, sent)
        except OSError as exc:  # EPIPE, ECONNRESET, a timeout: the consumer is gone or stuck
            if self.alive:
                log.warning("link %s closed: %s", self.name, exc)
            self.close()
            return False
        return True

    def _send_rest(self, parts: list[Any], sent: int) -> None:
        for part in parts:
            view = memoryview(part).cast("B")
            if sent >= len(view):
                sent -= len(view)
                continue
            self.sock.sendall(view[sent:])
            sent = 0

    def close(self) -> None:
        self.alive = False
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()


Attach = Callable[[dict[str, Any], socket.socket], bool]


class LinkListener:
    """The socket a producing process takes links on; each hello goes to *attach* (hello, socket):
    True if the producer took the link (it now owns the socket)."""

    def __init__(self, run: str, process: str, attach: Attach) -> None:
        self.path = link_path(run, process)
        self.path.parent.mkdir(mode=0o700, exist_ok=True)  # (the run's folder, beside its zenoh sockets)
        self.attach = attach
        self.closed = False
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._bind()
            self.sock.listen(64)
        except OSError:
            self.sock.close()
            raise
        self._thread = threading.Thread(target=self._accept_loop, name=f"vgr:links:{process}", daemon=True)
        self._thread.start()

    def _bind(self) -> None:
        """Bind the socket; a socket of an earlier process of this name that nobody answers on (it
        was killed) is taken over, anything else there is left alone (OSError)."""
        try:
            self.sock.bind(str(self.path))
            return
        except OSError:
            st = self.path.lstat()
            if not stat.S_ISSOCK(st.st_mode) or _answers(self.path):
                raise
        self.path.unlink()
        self.sock.bind(str(self.path))

    def _accept_loop(self) -> None:
        while not self.closed:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return  # closed
            try:
                self._handshake(conn)
            except Exception as exc:  # a malformed hello, a consumer that went away: that link only
                log.warning("a link request on %s was refused: %s", self.path, exc)
                with contextlib.suppress(OSError):
                    conn.close()

    def _handshake(self, conn: socket.socket) -> None:
        conn.settimeout(HANDSHAKE_TIMEOUT_S)
        (n,) = _HELLO_LEN.unpack(_recv_exactly(conn, _HELLO_LEN.size))
        if n > HELLO_MAX:
            raise ValueError(f"hello of {n} bytes (at most {HELLO_MAX})")
        hello = json.loads(_recv_exactly(conn, n))
        if not isinstance(hello, dict):
            raise ValueError("hello is not a JSON object")
        taken = self.attach(hello, conn)
        conn.sendall(ACCEPTED if taken else REFUSED)
        if not taken:
            conn.close()

    def close(self) -> None:
        """Take no more links (those taken stay with their ports) and remove the socket file."""
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()
        with contextlib.suppress(OSError):
            if stat.S_ISSOCK(self.path.lstat().st_mode):
                self.path.unlink()
        self._thread.join(2.0)


def _answers(path: Path) -> bool:
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(0.5)
        probe.connect(str(path))
        return True
    except OSError:
        return False
    finally:
        probe.close()


def _fill(sock: socket.socket, view: memoryview, got: int = 0) -> int:
    """Receive into *view* from byte *got* on until it is full or the link ends: the bytes it holds."""
    while got < len(view):
        k = sock.recv_into(view[got:])
        if not k:
            break
        got += k
    return got


def _recv_exactly(sock: socket.socket, n: int) -> bytes:
    buf = bytearray(n)
    got = _fill(sock, memoryview(buf))
    if got < n:
        raise ConnectionError(f"closed after {got} of {n} bytes")
    return bytes(buf)


def open_link(run: str, producer_process: str, hello: dict[str, Any]) -> socket.socket | None:
    """Ask *producer_process*'s listener for a link (*hello* says which): the socket, or None if
    there is no listener on this host, it refused, or it did not answer in time."""
    path = link_path(run, producer_process)
    if not path.exists():
        return None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.settimeout(HANDSHAKE_TIMEOUT_S)
        sock.connect(str(path))
        body = json.dumps(hello).encode()
        sock.sendall(_HELLO_LEN.pack(len(body)) + body)
        if _recv_exactly(sock, 1) != ACCEPTED:
            sock.close()
            return None
        sock.settimeout(None)  # (reads block: the reader thread waits for the next frame)
        return sock
    except OSError as exc:
        log.info("no link to %s: %s", path, exc)
        sock.close()
        return None


class FrameReader:
    """The consumer's end of a link: the (envelope, payload) frames in order, until the producer
    closes it (a frame cut short by a killed producer is dropped)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def frames(self) -> Iterator[tuple[bytes, bytes | memoryview]]:
        recv, unpack, head = self.sock.recv, FRAME.unpack_from, FRAME.size
        buf, off = b"", 0
        while True:
            try:
                data = recv(RECV_BYTES)
            except OSError:  # reset by a killed producer, or closed here
                return
            if not data:
                return
            buf, off = (buf[off:] + data, 0) if off < len(buf) else (data, 0)
            end = len(buf)
            while end - off >= head:
                n_env, n_payload = unpack(buf, off)
                stop = off + head + n_env + n_payload
                if stop > end:
                    if n_payload > RECV_BYTES:  # a large payload: the rest read into one buffer
                        frame = self._rest_of(buf, off, head + n_env + n_payload)
                        if frame is None:
                            return
                        yield frame[head : head + n_env].tobytes(), frame[head + n_env :]
                        buf, off, end = b"", 0, 0
                    break
                start = off + head
                yield buf[start : start + n_env], buf[start + n_env : stop]
                off = stop

    def _rest_of(self, buf: bytes, off: int, size: int) -> memoryview | None:
        """The frame of *size* bytes starting at *buf[off:]*, the rest received into it (None if the
        link ends first)."""
        frame = bytearray(size)
        have = len(buf) - off
        frame[:have] = buf[off:]
        view = memoryview(frame)
        try:
            if _fill(self.sock, view, have) < size:
                return None
        except OSError:
            return None
        return view.toreadonly()  # (as a zenoh payload's bytes: a numpy view of it is read-only)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()


def links_allowed(settings: Any, secured: bool) -> bool:
    """Whether a process with these zenoh *settings* (engine.recipe.model.ZenohSettings) links to
    processes of its host."""
    return settings.local_links and not secured and os.name == "posix" and hasattr(socket, "AF_UNIX")
