"""The live view serves clients that offer the Foxglove protocol by either name: ``foxglove.sdk.v1``
(what the SDK's server accepts) or only the older ``foxglove.websocket.v1`` (answered HTTP 400
before); a request that never ends its headers is cut off."""

from __future__ import annotations

import contextlib
import json
import socket
from urllib.parse import quote

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from engine.recording.live_view import LiveView
from engine.recording.view_proxy import MAX_HEADER_BYTES, answer_old_name, offer_new_name

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def view():
    v = LiveView(port=0, name="test")
    yield v
    v.close()


@pytest.mark.parametrize(
    "offered", [["foxglove.websocket.v1"], ["foxglove.sdk.v1"], ["foxglove.sdk.v1", "foxglove.websocket.v1"]]
)
def test_either_protocol_name_gets_the_server_info(view, offered):
    with connect(view.url, subprotocols=offered, open_timeout=5) as ws:
        assert ws.subprotocol in offered
        assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"


def test_the_rename_touches_only_the_protocol_header():
    req = b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n"
    new, renamed = offer_new_name(req)
    assert renamed and new == req.replace(b"foxglove.websocket.v1", b"foxglove.sdk.v1")
    both = b"GET / HTTP/1.1\r\nsec-websocket-protocol: foxglove.sdk.v1, foxglove.websocket.v1\r\n\r\n"
    assert offer_new_name(both) == (both, False)
    resp = b"HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    assert answer_old_name(resp) == resp.replace(b"sdk", b"websocket")


def test_a_request_whose_headers_never_end_is_closed(view):
    with socket.create_connection(("127.0.0.1", view.port), timeout=10) as s:
        s.sendall(b"GET / HTTP/1.1\r\n" + b"X: " + b"a" * (MAX_HEADER_BYTES + 5000))
        s.settimeout(10)
        with contextlib.suppress(ConnectionResetError):  # (closed with our bytes unread: a reset)
            assert s.recv(100) == b""  # closed, nothing forwarded


def test_with_a_token_only_a_viewer_whose_url_carries_it_is_served():
    token = "k3y+0f/the=v1ew-2f9a"  # (base64 characters: '+' is not a space here)
    v = LiveView(port=0, name="test", token=token)
    try:
        for given in (token, quote(token, safe="")):  # as written, and percent-encoded
            with connect(f"{v.url}/?token={given}", subprotocols=["foxglove.sdk.v1"], open_timeout=5) as ws:
                assert json.loads(ws.recv(timeout=5))["op"] == "serverInfo"
        for url in (v.url, f"{v.url}/?token=k3y", f"{v.url}/?token={token}x", f"{v.url}/?token={token}&token=a"):
            with pytest.raises(InvalidStatus) as refused:
                connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5)
            assert refused.value.response.status_code == 401, url
    finally:
        v.close()


def test_the_token_file_must_be_private_and_long_enough(tmp_path):
    from engine.cli.recording import read_view_token

    f = tmp_path / "view.token"
    f.write_text("0123456789abcdef-long-enough\n")
    f.chmod(0o600)
    assert read_view_token(str(f)) == "0123456789abcdef-long-enough"
    f.chmod(0o644)
    with pytest.raises(ValueError, match="can be read by its group or by others"):
        read_view_token(str(f))
    f.chmod(0o600)
    f.write_text("short\n")
    with pytest.raises(ValueError, match="at least 16 characters"):
        read_view_token(str(f))
    with pytest.raises(ValueError, match="no such file"):
        read_view_token(str(tmp_path / "none"))
