"""The live view serves clients that offer the Foxglove protocol by either name: ``foxglove.sdk.v1``
(what the SDK's server accepts) or only the older ``foxglove.websocket.v1`` (answered HTTP 400
before); a request that never ends its headers is cut off."""

from __future__ import annotations

import contextlib
import json
import socket

import pytest
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
