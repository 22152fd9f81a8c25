"""The unix-socket links between vgr processes of one host (engine.transport.local_link), without
processes: frames whole and in order however the byte stream is cut, a frame cut by a killed
producer dropped, a large frame read into one read-only buffer, a gone or stuck consumer dropping
the link, and the listener's handshake (malformed hellos refused, a stale socket taken over, a live
one left alone). The runs across processes are in test_processes.py and test_local_link_runs.py."""

from __future__ import annotations

import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import types
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.transport import local_link
from engine.transport.local_link import (
    FRAME,
    REFUSED,
    FrameReader,
    LinkListener,
    LinkSender,
    open_link,
)
from engine.transport.wire import WireSender

pytestmark = pytest.mark.timeout(60)


def frame_bytes(frames: list[tuple[bytes, bytes]]) -> bytes:
    return b"".join(FRAME.pack(len(e), len(p)) + e + p for e, p in frames)


def read_all(data: bytes, cuts: list[int], close_early: bool = False) -> list[tuple[bytes, bytes]]:
    """What a FrameReader yields for *data* written in pieces ending at *cuts*, then closed."""
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)

    def write() -> None:
        last = 0
        for cut in [*sorted(set(cuts)), len(data)]:
            a.sendall(data[last:cut])
            last = cut
        a.close()

    writer = threading.Thread(target=write)
    writer.start()
    got = [(bytes(e), bytes(p)) for e, p in FrameReader(b).frames()]
    writer.join(10)
    b.close()
    return got


frames_st = st.lists(st.tuples(st.binary(max_size=40), st.binary(max_size=3000)), max_size=12)


@settings(max_examples=60, deadline=None)
@given(frames=frames_st, cuts=st.lists(st.integers(min_value=0, max_value=40_000), max_size=10))
def test_frames_arrive_whole_and_in_order_however_the_stream_is_cut(frames, cuts):
    data = frame_bytes(frames)
    assert read_all(data, [c for c in cuts if c < len(data)]) == frames


def test_a_large_frame_is_read_into_one_read_only_buffer():
    big = os.urandom(local_link.RECV_BYTES * 3 + 17)
    frames = [(b"env-a", b"small"), (b"env-big", big), (b"env-c", b"after")]
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    writer = threading.Thread(target=lambda: (a.sendall(frame_bytes(frames)), a.close()))
    writer.start()
    got = list(FrameReader(b).frames())
    writer.join(10)
    assert [(bytes(e), bytes(p)) for e, p in got] == frames
    payload = got[1][1]
    assert isinstance(payload, memoryview) and payload.readonly  # a numpy view of it is read-only too


def test_a_frame_cut_short_by_a_killed_producer_is_dropped():
    frames = [(b"e1", b"one"), (b"e2", b"two")]
    cut = frame_bytes([(b"e3", b"x" * 500)])[:-100]  # the producer died while writing the third
    assert read_all(frame_bytes(frames) + cut, [7, 30]) == frames


def test_a_send_to_a_consumer_that_went_away_says_the_link_is_gone():
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    link = LinkSender(a, "src.out -> sink.in")
    assert link.send(b"env", b"payload")
    b.close()
    assert not link.send(b"env", b"payload")  # EPIPE: dropped, no exception into the stage
    assert not link.alive and not link.send(b"env", b"again")


def test_a_consumer_that_stopped_reading_drops_the_link_after_the_send_timeout(monkeypatch):
    monkeypatch.setattr(local_link, "SEND_TIMEOUT_S", 0.2)
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    link = LinkSender(a, "src.out -> sink.in")
    chunk = bytes(64 * 1024)
    sent = 0
    while link.send(b"env", chunk) and sent < 1000:  # the socket's buffer fills, then the wait ends it
        sent += 1
    assert sent < 1000 and not link.alive
    b.close()


# --------------------------------------------------------------------------- the listener


@pytest.fixture
def run_folder(monkeypatch):
    """A private socket folder of this test (short: a unix socket path has ~100 bytes)."""
    folder = Path(tempfile.mkdtemp(prefix="vgr-l-"))
    os.chmod(folder, 0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(folder))
    yield folder / "vgr"
    shutil.rmtree(folder, ignore_errors=True)


def raw_hello(path: Path, body: bytes) -> bytes:
    """Send *body* as a hello; the listener's answer (b"" if it closed without one)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(5)
        s.connect(str(path))
        s.sendall(struct.pack("<I", len(body)) + body)
        try:
            return s.recv(1)
        except ConnectionResetError:
            return b""


def test_the_listener_takes_what_it_is_asked_for_and_refuses_the_rest(run_folder):
    seen: list[dict] = []
    kept: list[socket.socket] = []

    def attach(hello: dict, sock: socket.socket) -> bool:
        seen.append(hello)
        if hello.get("port") == "out":
            kept.append(sock)
            return True
        return False

    listener = LinkListener("r1", "producer", attach)
    try:
        path = listener.path
        assert raw_hello(path, json.dumps({"port": "other"}).encode()) == REFUSED
        assert raw_hello(path, b"[1, 2]") == b""  # not an object: closed, attach never asked
        assert raw_hello(path, b"{not json") == b""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:  # a hello too long: closed unread
            s.settimeout(5)
            s.connect(str(path))
            s.sendall(struct.pack("<I", local_link.HELLO_MAX + 1))
            assert s.recv(1) == b""
        sock = open_link("r1", "producer", {"port": "out"})
        assert sock is not None and len(kept) == 1
        kept[0].sendall(FRAME.pack(1, 2) + b"e" + b"pl")  # the producer's end now carries frames
        assert [(bytes(e), bytes(p)) for e, p in _first(FrameReader(sock))] == [(b"e", b"pl")]
        sock.close()
        assert [h.get("port") for h in seen] == ["other", "out"]
    finally:
        listener.close()
    assert not path.exists()  # its socket file goes with it
    assert open_link("r1", "producer", {"port": "out"}) is None  # no listener: zenoh, at once


def _first(reader: FrameReader) -> list:
    for frame in reader.frames():
        return [frame]
    return []


def test_a_stale_socket_is_taken_over_and_a_live_one_left_alone(run_folder):
    path = local_link.link_path("r2", "producer")
    path.parent.mkdir(parents=True, mode=0o700)
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))  # bound and never listening: what a killed process leaves
    stale.close()
    first = LinkListener("r2", "producer", lambda hello, sock: False)
    try:
        assert raw_hello(path, b"{}") == REFUSED  # the new listener answers there
        with pytest.raises(OSError):
            LinkListener("r2", "producer", lambda hello, sock: False)  # a live one is not taken over
    finally:
        first.close()


class Puts:
    """A zenoh publisher's stand-in: what was put; nothing subscribes to it."""

    matching_status = types.SimpleNamespace(matching=False)

    def __init__(self) -> None:
        self.puts: list[tuple[bytes, bytes]] = []

    def put(self, payload: bytes, attachment: bytes) -> None:
        self.puts.append((bytes(payload), bytes(attachment)))

    def declare_matching_listener(self, handler: object) -> object:
        return handler


def test_a_port_whose_only_consumer_is_linked_puts_nothing_on_zenoh_until_the_link_is_lost():
    zenoh_side = Puts()
    sender = WireSender(zenoh_side, "src.out")
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    sender.add_link(LinkSender(a, "src.out -> sink.in"), zenoh_too=False)
    sender.send(b"one", b"env1")
    assert zenoh_side.puts == []
    b.settimeout(5)
    assert b.recv(100) == FRAME.pack(4, 3) + b"env1" + b"one"
    b.close()  # the consumer died: a consumer that rejoins listens on zenoh
    time.sleep(0.06)  # (not a burst: each message is sent at once)
    sender.send(b"two", b"env2")
    time.sleep(0.06)
    sender.send(b"three", b"env3")
    sender.close()
    assert zenoh_side.puts == [(b"two", b"env2"), (b"three", b"env3")]


def test_nothing_leaks_over_many_messages(tmp_path):
    """20 000 here; the same check over a million messages is ``python benchmarks/local_link.py --leak
    1000000`` (results/local_link_leak.json)."""
    out = tmp_path / "leak.json"
    script = Path(__file__).resolve().parents[2] / "benchmarks" / "local_link.py"
    done = subprocess.run(
        [sys.executable, str(script), "--leak", "20000", "--out", str(out)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    leak = json.loads(out.read_text())
    assert leak["whole_and_in_order"] == 20_000 and not leak["leaked"], leak
