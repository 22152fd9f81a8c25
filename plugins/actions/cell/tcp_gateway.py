"""The cell service's plain TCP text gateway: ASCII lines for robot controllers that cannot run zenoh.

ABB RAPID, KUKA KRL, FANUC Karel and URScript can open a TCP socket and send and read strings; the
gateway turns each line into a request document of the cell API (engine.run.cell.protocol), calls
the service with it and turns the reply document back into one line. Robot-vendor pose formats are
converted here, by the named functions of plugins.vendor_poses, and nowhere else.

Connection. ``listen`` is ``host:port`` (default ``127.0.0.1:50010``). Loopback peers are always
served; any other peer must be covered by ``allow`` (IP addresses or networks such as
``10.0.0.0/24``), and listening on a non-loopback address needs a non-empty ``allow``. A refused
peer gets ``ERROR,-,8,invalid_request,connection from <ip> refused: not in the gateway's allow list``
and is closed; beyond ``max_connections`` open connections a new one gets
``ERROR,-,7,busy,too many connections (<max_connections>)`` and is closed. A connection stays open
for any number of requests; requests on one connection are answered in order, one line each, and
several connections are served at once (the service answers ``busy`` while a cycle runs). A client
that does not read a reply for 5 s is dropped.

Lines. ASCII, ended by ``\\n`` (a ``\\r`` before it is ignored), at most 1024 bytes. Fields are
separated by commas; spaces around a field are ignored; commands are case-insensitive. Empty lines
are ignored. A line that is not ASCII, or is malformed in any way, is answered with an ``ERROR`` line
of code 8 and the connection goes on; a line longer than 1024 bytes is answered so and the
connection is closed; a connection closed in the middle of a line just ends (that line is not
answered). ``<id>`` is 1-64 characters of letters, digits and ``_ . : -``; sending a job
again with the same id gets the same reply again (never a second capture or move).

Poses are written in the gateway's ``format`` (one per gateway; the controller must use the same);
a quaternion must have norm 1 within 1e-3 (it is normalised), every value must be a finite decimal
number (``1.5``, ``-2e-3``; not ``nan``, ``inf``, ``1_0``):

=======  ======  ===================================================================================
format   values  meaning
=======  ======  ===================================================================================
``ur``   6       ``x,y,z`` (m), ``rx,ry,rz`` rotation vector (rad): URScript's ``p[...]``
``abb``  7       ``x,y,z`` (mm), ``q1,q2,q3,q4`` quaternion, w first: a robtarget's ``trans``/``rot``
``kuka`` 6       ``X,Y,Z`` (mm), ``A,B,C`` (deg, R = Rz(A) Ry(B) Rx(C)): a KRL ``FRAME``
``xyzq`` 7       ``x,y,z`` (m), ``qx,qy,qz,qw`` quaternion, w last (the API's own)
=======  ======  ===================================================================================

Requests (the pose sent is the robot's current flange/TCP pose in its base frame)::

    LOCATE,<id>,<count>[,<pose>]          count >= 1 parts wanted; pose optional (eye-in-hand needs it)
    GUIDE,<id>,<step>,<pose>[,<start pose>]   step >= 0 of an iterative guidance; start pose optional
    STATUS[,<id>]                          is the service ready, how many cycles, how fast

Replies (numbers with 9 significant digits; ``<code>`` and ``<status>`` from the table of
engine.run.cell.codes; ``<message>`` is always the last field, with commas written as ``;``, line
breaks as spaces, at most 200 characters)::

    LOCATE,<id>,<code>,<found>,<correction of part 1>,...,<correction of part found>,<status>,<message>
    GUIDE,<id>,<code>,<done 0|1>,<next pose>,<correction>,<status>,<message>
    STATUS,<id or ->,<code>,<ready 0|1>,<cycles>,<takt p50 ms>,<status>,<message>
    ERROR,<id or ->,<code>,<status>,<message>

``found`` is 0 unless the code is 0; then each part located adds its correction (in the reply's order).
GUIDE's ``next pose`` is the pose to move the flange to next and ``correction`` the correction
found so far; either is written as zeros of the format's width when the reply has none
(converged, refused, any code but 0). ``<takt p50 ms>`` is the median cycle time. ``ERROR`` lines
are the gateway's own answers (code 8: the line is malformed, the message says what; 7: too many
connections) or a failure of the service on the request (code 9, ``ERROR,<id>,9,fault,<exception>``,
logged with its traceback); their id is the request's when the line had a valid one, else ``-``.

Move on code 0 only. A correction ``C`` is applied by left-multiplying the taught poses ``P`` (both
in the robot's base frame): URScript ``pose_trans(C, P)``, RAPID ``PoseMult(C, P)``, KRL ``C:P``.
examples/cell/ has a URScript and a RAPID client.

Example (format ur)::

    > LOCATE,part-0017,1,0.4,-0.1,0.3,0,3.14159265,0
    < LOCATE,part-0017,0,1,0.00102,-0.0003,0,0,0,0.0021,ok,1 part located
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import math
import re
import socket
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from engine.run.cell.codes import Status
from engine.run.cell.protocol import API_VERSION, REQUEST_ID_RE, pose_doc, pose_from_doc
from engine.transforms import T_from_pose7
from plugins.vendor_poses import T_from_abb, T_from_kuka_abc, T_from_ur, abb_from_T, kuka_abc_from_T, ur_from_T

Handler = Callable[[str, dict[str, Any]], dict[str, Any]]  # (command, request document) -> reply document
Format = Literal["ur", "abb", "kuka", "xyzq"]

MAX_LINE = 1024  # bytes of a request line, its "\r\n" not counted
MAX_MESSAGE = 200  # characters of a reply's message field
SEND_TIMEOUT_S = 5.0  # a client that does not read its reply for this long is dropped
POLL_S = 0.25  # how often the accept loop and the connections look at close()
JOIN_S = 2.0  # close() waits this long in all for the threads
FIELD_NAMES: dict[str, tuple[str, ...]] = {
    "ur": ("x", "y", "z", "rx", "ry", "rz"),
    "abb": ("x", "y", "z", "q1", "q2", "q3", "q4"),
    "kuka": ("X", "Y", "Z", "A", "B", "C"),
    "xyzq": ("x", "y", "z", "qx", "qy", "qz", "qw"),
}
_NUMBER_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_COUNT_RE = re.compile(r"^\+?\d{1,9}$")


class GatewaySettings(BaseModel):
    """The ``gateway`` settings of a cell service."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    listen: str = "127.0.0.1:50010"  # host:port; port 0 = any free port
    allow: list[str] = []  # controller addresses or networks served besides loopback
    format: Format = "ur"
    max_connections: int = Field(default=8, ge=1, le=64)

    @field_validator("listen")
    @classmethod
    def _check_listen(cls, v: str) -> str:
        split_listen(v)
        return v

    @field_validator("allow")
    @classmethod
    def _check_allow(cls, v: list[str]) -> list[str]:
        for net in v:
            try:
                ipaddress.ip_network(net, strict=False)
            except ValueError:
                raise ValueError(f"allow: {net!r} is not an IP address or network (e.g. 10.0.0.0/24)") from None
        return v


def split_listen(listen: str) -> tuple[str, int]:
    """``(host, port)`` of ``host:port`` / ``[v6]:port`` (ValueError when it is not one)."""
    host, sep, port = listen.strip().rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"listen {listen!r}: write host:port, e.g. 127.0.0.1:50010 or [::1]:50010")
    return host, int(port)


def _ip(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        ip = ipaddress.ip_address(text)
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def is_loopback(host: str) -> bool:
    """Whether *host* (an IP address or ``localhost``) is a loopback address."""
    ip = _ip(host)
    return host == "localhost" if ip is None else ip.is_loopback


def allowed(peer_ip: str, allow: Sequence[str]) -> bool:
    """Whether a peer at *peer_ip* may connect: loopback always, others when *allow* covers them."""
    ip = _ip(peer_ip.split("%", 1)[0])
    if ip is None:
        return False
    if ip.is_loopback:
        return True
    for entry in allow:
        net = ipaddress.ip_network(entry, strict=False)
        if net.version == ip.version and ip in net:
            return True
    return False


class LineError(ValueError):
    """A malformed request line (answered with an ERROR line of code 8)."""


# -- lines to request documents --------------------------------------------------------------------
def _number(field: str, what: str) -> float:
    try:
        v = float(field)
    except ValueError:
        v = None
    if v is not None and not math.isfinite(v):
        raise LineError(f"{what} {field!r} is not finite")
    if v is None or not _NUMBER_RE.match(field):
        raise LineError(f"{what} {field!r} is not a number")
    return v


def _count(field: str, what: str, minimum: int) -> int:
    if not _COUNT_RE.match(field) or int(field) < minimum:
        raise LineError(f"{what} {field!r} is not an integer >= {minimum}")
    return int(field)


def _request_id(field: str) -> str:
    if REQUEST_ID_RE.match(field):
        return field
    raise LineError(f"id {field!r}: 1-64 characters of letters, digits and _ . : -")


def T_from_values(fmt: str, values: Sequence[float]) -> np.ndarray:
    """The 4x4 (m) of one pose written in gateway format *fmt* (LineError when it is not a pose)."""
    if fmt in ("abb", "xyzq"):
        q = np.asarray(values[3:], dtype=float)
        norm = float(np.linalg.norm(q))
        if not math.isclose(norm, 1.0, abs_tol=1e-3):
            raise LineError(f"the quaternion has norm {norm:.6f}, not 1")
        if fmt == "abb":
            return T_from_abb(values[:3], values[3:])
        return T_from_pose7(values[:3], q)
    return T_from_ur(values) if fmt == "ur" else T_from_kuka_abc(values)


def values_from_T(fmt: str, T: np.ndarray) -> list[float]:
    """One pose (4x4, m) written in gateway format *fmt*."""
    if fmt == "ur":
        return [float(v) for v in ur_from_T(T)]
    if fmt == "abb":
        p, q = abb_from_T(T)
        return [float(v) for v in (*p, *q)]
    if fmt == "kuka":
        return [float(v) for v in kuka_abc_from_T(T)]
    doc = pose_doc(T)
    return doc["xyz_m"] + doc["quat_xyzw"]


def _poses(fmt: str, fields: list[str], counts: tuple[int, ...], command: str) -> list[dict[str, Any]]:
    names = FIELD_NAMES[fmt]
    width = len(names)
    if len(fields) not in tuple(c * width for c in counts):
        wanted = " or ".join(str(c * width) for c in counts)
        raise LineError(f"{command} takes {wanted} pose values in format {fmt} ({','.join(names)}), got {len(fields)}")
    docs = []
    for k in range(len(fields) // width):
        chunk = fields[k * width : (k + 1) * width]
        values = [_number(f, f"pose value {names[i]}") for i, f in enumerate(chunk)]
        try:
            docs.append(pose_doc(T_from_values(fmt, values)))
        except LineError:
            raise
        except ValueError as exc:  # e.g. a rotation no controller would send
            raise LineError(f"pose {k + 1} is not a pose: {exc}") from None
    return docs


def parse_line(line: str, fmt: str) -> tuple[str, dict[str, Any]]:
    """``(command, request document)`` of one request line (LineError when it is malformed)."""
    fields = [f.strip() for f in line.split(",")]
    command = fields[0].upper()
    doc: dict[str, Any] = {"api": API_VERSION}
    if command == "STATUS":
        if len(fields) > 2:
            raise LineError(f"STATUS takes at most an id, got {len(fields) - 1} fields")
        if len(fields) == 2 and fields[1]:
            doc["id"] = _request_id(fields[1])
        return "status", doc
    if command not in ("LOCATE", "GUIDE"):
        raise LineError(f"unknown command {fields[0][:40]!r}: the gateway takes LOCATE, GUIDE and STATUS")
    if len(fields) < 3:
        raise LineError(f"{command} needs an id and a {'count' if command == 'LOCATE' else 'step'}")
    doc["id"] = _request_id(fields[1])
    if command == "LOCATE":
        doc["count"] = _count(fields[2], "count", 1)
        poses = _poses(fmt, fields[3:], (0, 1), command)
        if poses:
            doc["pose"] = poses[0]
        return "locate", doc
    doc["step"] = _count(fields[2], "step", 0)
    poses = _poses(fmt, fields[3:], (1, 2), command)
    doc["pose"] = poses[0]
    if len(poses) == 2:
        doc["start_pose"] = poses[1]
    return "guide", doc


# -- reply documents to lines ----------------------------------------------------------------------
def _text(value: Any, limit: int = MAX_MESSAGE) -> str:
    s = " ".join(str(value).splitlines()).replace(",", ";")
    s = "".join(c if " " <= c <= "~" else "?" for c in s)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _num(v: float) -> str:
    return format(float(v), ".9g")


def error_line(request_id: str | None, status: Status, message: str) -> str:
    """An ERROR line (the gateway's own answer)."""
    return f"ERROR,{request_id or '-'},{int(status)},{status.name},{_text(message)}"


def reply_line(command: str, request_id: str | None, reply: dict[str, Any], fmt: str) -> str:
    """The line of the reply document *reply* to *command* (ValueError when it is not a reply)."""
    if not isinstance(reply, dict):
        raise ValueError(f"the handler returned {type(reply).__name__}, not a reply document")
    status = str(reply["status"])
    code = int(reply["code"])
    result = reply.get("result") or {}
    rid = request_id or "-"
    zeros = ["0"] * len(FIELD_NAMES[fmt])

    def pose(doc: Any, name: str) -> list[str]:
        if code != 0 or doc is None:
            return zeros
        return [_num(v) for v in values_from_T(fmt, pose_from_doc(doc, name))]

    if command == "locate":
        parts = (result.get("parts") or []) if code == 0 else []
        fields = [str(len(parts))]
        for i, part in enumerate(parts):
            fields += pose(part["correction"], f"parts[{i}].correction")
    elif command == "guide":
        fields = ["1" if result.get("converged") else "0"]
        fields += pose(result.get("next_pose"), "next_pose") + pose(result.get("correction"), "correction")
    else:
        takt = (result.get("takt_ms") or {}).get("p50") or 0.0
        fields = ["1" if result.get("ready") else "0", str(int(result.get("cycles") or 0)), _num(takt)]
    return ",".join([command.upper(), rid, str(code), *fields, _text(status, 40), _text(reply.get("message", ""))])


# -- the server ------------------------------------------------------------------------------------
class TcpGateway:
    """A TCP server answering request lines with *handle* (see the module docstring)."""

    def __init__(self, handle: Handler, settings: GatewaySettings, log: logging.Logger | None = None) -> None:
        self.handle = handle
        self.settings = settings
        self.log = log or logging.getLogger("vgr.cell.gateway")
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._server: socket.socket | None = None
        self._accept_thread: threading.Thread | None = None
        self._connections: dict[int, tuple[socket.socket, threading.Thread]] = {}
        self._serial = 0

    @property
    def address(self) -> tuple[str, int]:
        """The bound ``(host, port)``."""
        if self._server is None:
            raise RuntimeError("the gateway is not started")
        host, port = self._server.getsockname()[:2]
        return host, port

    def start(self) -> None:
        """Bind, listen and start accepting (ValueError when it cannot)."""
        listen = self.settings.listen
        host, port = split_listen(listen)
        if not is_loopback(host) and not self.settings.allow:
            raise ValueError(f"listening on {host} needs an allow list of controller addresses (gateway.allow)")
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            self._server = socket.create_server((host, port), family=family, backlog=self.settings.max_connections)
        except OSError as exc:
            raise ValueError(f"cannot listen on {listen}: {exc.strerror or exc}") from None
        self._server.settimeout(POLL_S)
        self._accept_thread = threading.Thread(target=self._accept_loop, name="vgr-gateway-accept", daemon=True)
        self._accept_thread.start()
        self.log.info("TCP gateway on %s:%d (format %s)", *self.address, self.settings.format)

    def close(self) -> None:
        """Stop accepting, close every connection and wait (at most ~2 s) for the threads."""
        self._stop.set()
        if self._server is not None:
            with contextlib.suppress(OSError):
                self._server.shutdown(socket.SHUT_RDWR)  # wakes accept() at once where the OS does
        with self._lock:
            connections = list(self._connections.values())
        for conn, _ in connections:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        threads = [t for _, t in connections]
        if self._accept_thread is not None:
            threads.insert(0, self._accept_thread)
        deadline = time.monotonic() + JOIN_S
        for t in threads:
            t.join(max(0.0, deadline - time.monotonic()))
        if self._server is not None:
            self._server.close()

    def _accept_loop(self) -> None:
        assert self._server is not None
        while not self._stop.is_set():
            try:
                conn, peer = self._server.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if not self._stop.is_set():
                    self.log.warning("gateway accept failed: %s", exc)
                    self._stop.wait(POLL_S)
                continue
            self._admit(conn, peer[0])

    def _admit(self, conn: socket.socket, peer_ip: str) -> None:
        if not allowed(peer_ip, self.settings.allow):
            self.log.warning("gateway: connection from %s refused (not in the allow list)", peer_ip)
            msg = f"connection from {peer_ip} refused: not in the gateway's allow list"
            self._refuse(conn, error_line(None, Status.invalid_request, msg))
            return
        n = self.settings.max_connections
        with self._lock:
            full = len(self._connections) >= n
            if not full:
                self._serial += 1
                args, name = (self._serial, conn, peer_ip), f"vgr-gateway-{peer_ip}-{self._serial}"
                thread = threading.Thread(target=self._serve, args=args, name=name, daemon=True)
                self._connections[self._serial] = (conn, thread)
        if full:
            self.log.warning("gateway: connection from %s refused: %d connections open", peer_ip, n)
            self._refuse(conn, error_line(None, Status.busy, f"too many connections ({n})"))
        else:
            thread.start()

    def _refuse(self, conn: socket.socket, line: str) -> None:
        conn.settimeout(1.0)
        with contextlib.suppress(OSError):
            conn.sendall(line.encode() + b"\n")
            conn.shutdown(socket.SHUT_WR)
            conn.settimeout(0.05)
            conn.recv(65536)  # what the client sent at once: closing on unread input would reset the line away
        conn.close()

    def _serve(self, key: int, conn: socket.socket, peer_ip: str) -> None:
        self.log.info("gateway: %s connected", peer_ip)
        buf = bytearray()
        try:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            while not self._stop.is_set():
                conn.settimeout(POLL_S)
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                if not chunk:
                    break
                buf += chunk
                if not self._lines(conn, buf):
                    break
        except OSError as exc:
            if not self._stop.is_set():
                self.log.info("gateway: %s dropped: %s", peer_ip, exc)
        finally:
            with self._lock:
                self._connections.pop(key, None)
            conn.close()
            self.log.info("gateway: %s disconnected", peer_ip)

    def _lines(self, conn: socket.socket, buf: bytearray) -> bool:
        """Answer the complete lines in *buf* (removing them); False when the connection must close."""
        while (end := buf.find(b"\n")) >= 0:
            raw = bytes(buf[:end]).removesuffix(b"\r")
            del buf[: end + 1]
            if len(raw) > MAX_LINE:
                break
            line = self._answer(raw)
            if line is not None:
                self._send(conn, line)
        else:
            if len(buf) <= MAX_LINE + 1:
                return True
        self._send(conn, error_line(None, Status.invalid_request, f"line longer than {MAX_LINE} bytes: closing"))
        self._hang_up(conn)
        return False

    def _hang_up(self, conn: socket.socket) -> None:
        """Close our side, then drain (bounded) so that unread input does not reset the reply away."""
        conn.shutdown(socket.SHUT_WR)
        conn.settimeout(POLL_S)
        for _ in range(8):
            try:
                if not conn.recv(65536):
                    return
            except TimeoutError:
                continue

    def _send(self, conn: socket.socket, line: str) -> None:
        conn.settimeout(SEND_TIMEOUT_S)  # a client that does not read is dropped (OSError)
        conn.sendall(line.encode("ascii") + b"\n")

    def _answer(self, raw: bytes) -> str | None:
        """The reply line to one request line (None for an empty line)."""
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            return error_line(None, Status.invalid_request, "the line is not ASCII")
        if not text:
            return None
        fmt = self.settings.format
        try:
            command, doc = parse_line(text, fmt)
        except LineError as exc:
            fields = text.split(",")
            rid = fields[1].strip() if len(fields) > 1 and REQUEST_ID_RE.match(fields[1].strip()) else None
            return error_line(rid, Status.invalid_request, str(exc))
        rid = doc.get("id")
        try:
            reply = self.handle(command, doc)
        except Exception as exc:
            self.log.exception("gateway: the handler failed on %s %s", command, rid or "")
            return error_line(rid, Status.fault, f"{type(exc).__name__}: {exc}")
        try:
            return reply_line(command, rid, reply, fmt)
        except (KeyError, TypeError, ValueError) as exc:
            self.log.error("gateway: cannot write the reply %r: %s", reply, exc)
            return error_line(rid, Status.fault, f"the service's reply cannot be written as a line: {exc}")


def start_gateway(handle: Handler, settings: dict[str, Any], log: logging.Logger | None = None) -> TcpGateway:
    """A started gateway from a ``gateway`` settings mapping (ValueError with readable text)."""
    try:
        parsed = GatewaySettings.model_validate(settings)
    except ValidationError as exc:
        lines = [f"{'.'.join(str(p) for p in e['loc']) or 'gateway'}: {e['msg']}" for e in exc.errors()]
        raise ValueError("gateway settings: " + "; ".join(lines)) from None
    gateway = TcpGateway(handle, parsed, log)
    gateway.start()
    return gateway
