"""The live view's front door: accepts both names of the Foxglove WebSocket protocol.

The Foxglove protocol was renamed: the ``foxglove-sdk`` server vgr uses accepts only the
subprotocol ``foxglove.sdk.v1`` and answers HTTP 400 to a client that offers only the older name
``foxglove.websocket.v1``, which viewers still send (Lichtblick before 1.17, roslibjs-foxglove, the
``foxglove/ws-protocol`` clients); the two protocols are the same but for the name
(https://github.com/orgs/foxglove/discussions/1131). So the SDK server listens on a loopback port of
its own and this proxy listens where the user asked: it reads the client's HTTP upgrade request
(at most ``MAX_HEADER_BYTES``, within ``HANDSHAKE_TIMEOUT_S``), offers ``foxglove.sdk.v1`` in place
of ``foxglove.websocket.v1`` when only the old name is offered, gives the old name back in the
server's answer, and from then on copies the bytes both ways unchanged. A request that does not
end its headers in time or in size is closed.

With a *token* (``vgr run --view-token-file``), the proxy serves only a request whose URL carries it
(``ws://HOST:PORT/?token=TOKEN``, compared in constant time); any other gets ``401 Unauthorized``
and is closed before it reaches the server.
"""

from __future__ import annotations

import contextlib
import hmac
import logging
import re
import socket
import threading
from urllib.parse import unquote, urlsplit

log = logging.getLogger("vgr.view")

OLD, NEW = b"foxglove.websocket.v1", b"foxglove.sdk.v1"
MAX_HEADER_BYTES = 16384
HANDSHAKE_TIMEOUT_S = 5.0
_PROTOCOL_LINE = re.compile(rb"(?im)^(sec-websocket-protocol:)([^\r\n]*)")


def offer_new_name(request: bytes) -> tuple[bytes, bool]:
    """The request with the new protocol name offered where only the old one is; True if rewritten."""
    m = _PROTOCOL_LINE.search(request)
    if m is None or NEW in m.group(2) or OLD not in m.group(2):
        return request, False
    return request[: m.start(2)] + m.group(2).replace(OLD, NEW) + request[m.end(2) :], True


def answer_old_name(response: bytes) -> bytes:
    """The server's answer with the protocol it chose named as the client offered it."""
    m = _PROTOCOL_LINE.search(response)
    if m is None:
        return response
    return response[: m.start(2)] + m.group(2).replace(NEW, OLD) + response[m.end(2) :]


UNAUTHORIZED = b"HTTP/1.1 401 Unauthorized\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"


def carries_token(request: bytes, token: str) -> bool:
    """Does the request line's URL carry ``token=<token>`` (once) in its query? The value is taken
    as written or percent-decoded (a ``+`` of a base64 token is a ``+``, not a space)."""
    line = request.split(b"\r\n", 1)[0].decode("latin-1")
    parts = line.split(" ")
    if len(parts) != 3:
        return False
    given = [v for k, _, v in (f.partition("=") for f in urlsplit(parts[1]).query.split("&")) if k == "token"]
    if len(given) != 1:
        return False
    want = token.encode()
    return hmac.compare_digest(given[0].encode(), want) | hmac.compare_digest(unquote(given[0]).encode(), want)


def _read_headers(sock: socket.socket) -> bytes | None:
    """Bytes up to and including the first blank line (and any that came with them), or None."""
    data = b""
    while b"\r\n\r\n" not in data:
        if len(data) > MAX_HEADER_BYTES:
            return None
        chunk = sock.recv(4096)
        if not chunk:
            return None
        data += chunk
    return data


def _pump(src: socket.socket, dst: socket.socket) -> None:
    with contextlib.suppress(OSError):
        while chunk := src.recv(65536):
            dst.sendall(chunk)
    with contextlib.suppress(OSError):
        dst.shutdown(socket.SHUT_WR)


class ProtocolNameProxy:
    """Listens on *host*:*port* (0: a free one, then ``port`` says which) and forwards each
    connection to the SDK server on 127.0.0.1:*upstream_port* (see the module docstring); with
    *token*, only the requests that carry it."""

    def __init__(self, host: str, port: int, upstream_port: int, token: str | None = None) -> None:
        self._token = token
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = socket.socket(family, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port))
        except OSError:
            self._listener.close()
            raise
        self._listener.listen(16)
        self.port = int(self._listener.getsockname()[1])
        self._upstream = upstream_port
        self._closed = threading.Event()
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, name="vgr-view-proxy", daemon=True).start()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self._listener.accept()
            except OSError:
                return  # closed
            threading.Thread(target=self._serve, args=(client,), name="vgr-view-conn", daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        upstream = None
        try:
            client.settimeout(HANDSHAKE_TIMEOUT_S)
            request = _read_headers(client)
            if request is None:
                return
            if self._token is not None and not carries_token(request, self._token):
                log.warning("live view: refused a viewer without the token (%s)", client.getpeername())
                client.sendall(UNAUTHORIZED)
                return
            request, renamed = offer_new_name(request)
            upstream = socket.create_connection(("127.0.0.1", self._upstream), timeout=HANDSHAKE_TIMEOUT_S)
            upstream.sendall(request)
            response = _read_headers(upstream)
            if response is None:
                return
            client.sendall(answer_old_name(response) if renamed else response)
            client.settimeout(None)
            upstream.settimeout(None)
            with self._lock:
                if self._closed.is_set():
                    return
                self._open.update((client, upstream))
            back = threading.Thread(target=_pump, args=(upstream, client), daemon=True)
            back.start()
            _pump(client, upstream)
            back.join()
        except OSError as exc:
            log.debug("live view connection: %s", exc)
        finally:
            for s in (client, upstream):
                if s is not None:
                    with self._lock:
                        self._open.discard(s)
                    s.close()

    def close(self) -> None:
        """Stop accepting and cut every open connection."""
        self._closed.set()
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)  # (wakes the accept; close alone may not)
        self._listener.close()
        with self._lock:
            for s in self._open:
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
