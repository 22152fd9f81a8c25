"""The TCP text gateway, driven through real sockets on 127.0.0.1 with a fake cell service."""

from __future__ import annotations

import contextlib
import ipaddress
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from engine.run.cell.protocol import pose_doc, pose_from_doc, reply_doc
from engine.transforms import T_from_pose7, T_from_rotvec
from plugins.actions.cell import tcp_gateway
from plugins.actions.cell.tcp_gateway import GatewaySettings, TcpGateway, allowed, start_gateway
from plugins.vendor_poses import T_from_abb, T_from_kuka_abc, T_from_ur, abb_from_T, kuka_abc_from_T, ur_from_T

TIMEOUT_S = 5.0
FORMATS = ("ur", "abb", "kuka", "xyzq")
WIDTH = {"ur": 6, "abb": 7, "kuka": 6, "xyzq": 7}

T_ROBOT = T_from_rotvec(np.array([0.3, -2.9, 0.2]), np.array([0.412, -0.137, 0.295]))
T_START = T_from_rotvec(np.array([0.1, 3.0, -0.05]), np.array([0.4, -0.1, 0.35]))
CORRECTIONS = [
    T_from_rotvec(np.array([0.002, -0.001, 0.0131]), np.array([0.00123, -0.00047, 0.0002])),
    T_from_rotvec(np.array([-0.004, 0.003, -0.021]), np.array([-0.0021, 0.0011, -0.0003])),
    T_from_rotvec(np.array([0.0, 0.0, 0.5]), np.array([0.01, 0.02, 0.0])),
]


def vendor_values(fmt: str, T: np.ndarray) -> list[float]:
    """*T* written by the named vendor function of *fmt*."""
    if fmt == "ur":
        return list(ur_from_T(T))
    if fmt == "abb":
        p, q = abb_from_T(T)
        return [*p, *q]
    if fmt == "kuka":
        return list(kuka_abc_from_T(T))
    doc = pose_doc(T)
    return doc["xyz_m"] + doc["quat_xyzw"]


def T_of_values(fmt: str, values: list[float]) -> np.ndarray:
    """The 4x4 of vendor values by the named vendor function of *fmt*."""
    if fmt == "ur":
        return T_from_ur(values)
    if fmt == "abb":
        return T_from_abb(values[:3], values[3:])
    if fmt == "kuka":
        return T_from_kuka_abc(values)
    return T_from_pose7(values[:3], values[3:])


def text(values: list[float]) -> str:
    return ",".join(repr(float(v)) for v in values)


class FakeService:
    """Records (command, document) and answers with canned reply documents."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, dict[str, Any]]] = []
        self.respond: Callable[[str, dict[str, Any]], dict[str, Any]] = self.default
        self.lock = threading.Lock()

    def __call__(self, command: str, doc: dict[str, Any]) -> dict[str, Any]:
        with self.lock:
            self.calls.append((command, doc))
        return self.respond(command, doc)

    @staticmethod
    def default(command: str, doc: dict[str, Any]) -> dict[str, Any]:
        rid = doc.get("id")
        result: dict[str, Any]
        if command == "locate":
            result = {"parts": [{"correction": pose_doc(CORRECTIONS[0])}]}
            return reply_doc("sim", command, rid, "ok", "1 part located", cycle=1, result=result)
        if command == "guide":
            result = {"converged": False, "next_pose": pose_doc(T_START), "correction": pose_doc(CORRECTIONS[1])}
            return reply_doc("sim", command, rid, "ok", "step 1", cycle=2, result=result)
        result = {"ready": True, "cycles": 17, "takt_ms": {"p50": 412.5, "p95": 480.0}}
        return reply_doc("sim", command, rid, "ok", "ready", result=result)


class Client:
    def __init__(self, address: tuple[str, int]) -> None:
        self.sock = socket.create_connection(address, timeout=TIMEOUT_S)
        self.file = self.sock.makefile("rb")

    def send(self, line: str | bytes) -> None:
        self.sock.sendall((line.encode() if isinstance(line, str) else line) + b"\n")

    def read(self) -> str:
        """One reply line without its newline ("" when the gateway closed the connection)."""
        return self.file.readline(64 * 1024).decode("ascii").removesuffix("\n")

    def ask(self, line: str | bytes) -> str:
        self.send(line)
        return self.read()

    def close(self) -> None:
        self.file.close()
        self.sock.close()


@contextlib.contextmanager
def running(fmt: str = "ur", **kw: Any) -> Iterator[tuple[TcpGateway, FakeService]]:
    service = FakeService()
    gateway = TcpGateway(service, GatewaySettings.model_validate({"listen": "127.0.0.1:0", "format": fmt, **kw}))
    gateway.start()
    try:
        yield gateway, service
    finally:
        gateway.close()


@pytest.fixture
def ur() -> Iterator[tuple[TcpGateway, FakeService, Client]]:
    with running("ur") as (gateway, service):
        client = Client(gateway.address)
        yield gateway, service, client
        client.close()


def assert_pose(doc: dict[str, Any], T: np.ndarray, tol: float = 1e-9) -> None:
    np.testing.assert_allclose(pose_from_doc(doc), T, atol=tol)


# -- requests -----------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", FORMATS)
def test_locate_request_converts_the_pose_with_the_vendor_function(fmt: str) -> None:
    values = vendor_values(fmt, T_ROBOT)
    with running(fmt) as (gateway, service):
        client = Client(gateway.address)
        reply = client.ask(f"locate , part-1 ,2,{text(values)}\r")
        client.close()
    assert reply.startswith("LOCATE,part-1,0,1,")
    [(command, doc)] = service.calls
    assert command == "locate"
    assert set(doc) == {"api", "id", "count", "pose"}
    assert (doc["api"], doc["id"], doc["count"]) == (1, "part-1", 2)
    assert_pose(doc["pose"], T_of_values(fmt, values))
    assert_pose(doc["pose"], T_ROBOT)


def test_locate_without_a_pose_has_no_pose_key(ur: Any) -> None:
    _, service, client = ur
    assert client.ask("LOCATE,p2,1").startswith("LOCATE,p2,0,")
    assert service.calls == [("locate", {"api": 1, "id": "p2", "count": 1})]


@pytest.mark.parametrize("fmt", FORMATS)
def test_guide_request_with_and_without_start_pose(fmt: str) -> None:
    robot, start = vendor_values(fmt, T_ROBOT), vendor_values(fmt, T_START)
    with running(fmt) as (gateway, service):
        client = Client(gateway.address)
        client.ask(f"GUIDE,g-1,0,{text(robot)}")
        client.ask(f"Guide,g-2,3,{text(robot)},{text(start)}")
        client.close()
    (c1, d1), (c2, d2) = service.calls
    assert (c1, c2) == ("guide", "guide")
    assert set(d1) == {"api", "id", "step", "pose"} and (d1["id"], d1["step"]) == ("g-1", 0)
    assert set(d2) == {"api", "id", "step", "pose", "start_pose"} and (d2["id"], d2["step"]) == ("g-2", 3)
    for d in (d1, d2):
        assert_pose(d["pose"], T_of_values(fmt, robot))
    assert_pose(d2["start_pose"], T_of_values(fmt, start))
    assert_pose(d2["start_pose"], T_START)


def test_ur_pose_string_round_trips_to_the_same_transform(ur: Any) -> None:
    _, service, client = ur
    line = "0.412,-0.137,0.295,0.3,-2.9,0.2"
    client.ask(f"LOCATE,r,1,{line}")
    assert_pose(service.calls[0][1]["pose"], T_from_ur([float(v) for v in line.split(",")]))


def test_status_request_and_reply(ur: Any) -> None:
    _, service, client = ur
    assert client.ask("status") == "STATUS,-,0,1,17,412.5,ok,ready"
    assert client.ask("STATUS,st-9") == "STATUS,st-9,0,1,17,412.5,ok,ready"
    assert service.calls == [("status", {"api": 1}), ("status", {"api": 1, "id": "st-9"})]
    service.respond = lambda c, d: reply_doc("sim", c, None, "stopping", "shutting down")
    assert client.ask("STATUS") == "STATUS,-,10,0,0,0,stopping,shutting down"


# -- replies ------------------------------------------------------------------------------------
def fields_of(line: str) -> list[str]:
    return line.split(",")


@pytest.mark.parametrize("fmt", FORMATS)
def test_locate_reply_carries_each_correction_in_the_format(fmt: str) -> None:
    def three(command: str, doc: dict[str, Any]) -> dict[str, Any]:
        parts = [{"correction": pose_doc(C), "score": 0.9} for C in CORRECTIONS]
        return reply_doc("sim", command, doc["id"], "ok", "3 parts, best first", cycle=4, result={"parts": parts})

    w = WIDTH[fmt]
    with running(fmt) as (gateway, service):
        client = Client(gateway.address)
        one = fields_of(client.ask("LOCATE,a,1"))
        service.respond = three
        many = fields_of(client.ask("LOCATE,b,3"))
        client.close()
    assert one[:4] == ["LOCATE", "a", "0", "1"] and one[-2:] == ["ok", "1 part located"] and len(one) == 6 + w
    np.testing.assert_allclose(T_of_values(fmt, [float(v) for v in one[4 : 4 + w]]), CORRECTIONS[0], atol=1e-8)
    assert many[:4] == ["LOCATE", "b", "0", "3"] and len(many) == 6 + 3 * w
    for i, C in enumerate(CORRECTIONS):
        values = [float(v) for v in many[4 + i * w : 4 + (i + 1) * w]]
        np.testing.assert_allclose(T_of_values(fmt, values), C, atol=1e-8)
    assert many[-2:] == ["ok", "3 parts; best first"]


def test_locate_refusal_has_found_zero(ur: Any) -> None:
    _, service, client = ur
    service.respond = lambda c, d: reply_doc("sim", c, d["id"], "no_part", "nothing matched\nthe template", cycle=5)
    assert client.ask("LOCATE,p3,1") == "LOCATE,p3,1,0,no_part,nothing matched the template"
    # a non-ok reply that still carries parts shows none: motion is allowed on code 0 only
    parts = {"parts": [{"correction": pose_doc(CORRECTIONS[0])}]}
    service.respond = lambda c, d: reply_doc("sim", c, d["id"], "ambiguous", "2 fits", result=parts)
    assert client.ask("LOCATE,p4,1") == "LOCATE,p4,2,0,ambiguous,2 fits"


def test_guide_replies(ur: Any) -> None:
    _, service, client = ur
    f = fields_of(client.ask("GUIDE,g1,0,0.4,-0.1,0.3,0,3.1,0"))
    assert f[:4] == ["GUIDE", "g1", "0", "0"] and len(f) == 4 + 12 + 2 and f[-2:] == ["ok", "step 1"]
    np.testing.assert_allclose(T_from_ur([float(v) for v in f[4:10]]), T_START, atol=1e-8)
    np.testing.assert_allclose(T_from_ur([float(v) for v in f[10:16]]), CORRECTIONS[1], atol=1e-8)
    done = {"converged": True, "correction": pose_doc(CORRECTIONS[2])}
    service.respond = lambda c, d: reply_doc("sim", c, d["id"], "ok", "converged", result=done)
    f = fields_of(client.ask("GUIDE,g2,4,0.4,-0.1,0.3,0,3.1,0"))
    assert f[:4] == ["GUIDE", "g2", "0", "1"] and f[4:10] == ["0"] * 6 and f[-2:] == ["ok", "converged"]
    np.testing.assert_allclose(T_from_ur([float(v) for v in f[10:16]]), CORRECTIONS[2], atol=1e-8)
    service.respond = lambda c, d: reply_doc("sim", c, d["id"], "out_of_limits", "step of 40 mm: limit 10 mm")
    assert client.ask("GUIDE,g3,1,0.4,-0.1,0.3,0,3.1,0") == ",".join(
        ["GUIDE", "g3", "3", "0", *["0"] * 12, "out_of_limits", "step of 40 mm: limit 10 mm"]
    )


# -- malformed lines ----------------------------------------------------------------------------
BAD_LINES = [
    ("LOCATE,p,1,0.4,-0.1,abc,0,3.1,0", "not a number"),
    ("LOCATE,p,1,0.4,-0.1,0.3,0,3.1", "6 pose values"),
    ("LOCATE,p,1,0.4,-0.1,nan,0,3.1,0", "not finite"),
    ("LOCATE,p,1,0.4,-0.1,inf,0,3.1,0", "not finite"),
    ("LOCATE,p,1,0.4,-0.1,1e999,0,3.1,0", "not finite"),
    ("LOCATE,p,1,1_0,-0.1,0.3,0,3.1,0", "not a number"),
    ("LOCATE,p,0", "count"),
    ("LOCATE,p,1.5", "count"),
    ("LOCATE,p", "needs an id"),
    ("LOCATE,,1", "id"),
    ("LOCATE,a b,1", "id"),
    ("GUIDE,g,-1,0.4,-0.1,0.3,0,3.1,0", "step"),
    ("GUIDE,g,0", "pose values"),
    ("STATUS,a,b", "at most an id"),
    ("MOVE,p,1", "unknown command"),
]


@pytest.mark.parametrize(("line", "why"), BAD_LINES)
def test_a_malformed_line_gets_code_8_and_the_connection_goes_on(ur: Any, line: str, why: str) -> None:
    _, service, client = ur
    reply = client.ask(line)
    f = fields_of(reply)
    assert f[0] == "ERROR" and f[2:4] == ["8", "invalid_request"] and why in f[4], reply
    assert len(f) == 5
    assert service.calls == []
    assert client.ask("STATUS") == "STATUS,-,0,1,17,412.5,ok,ready"


def test_a_malformed_line_echoes_a_valid_id(ur: Any) -> None:
    _, _, client = ur
    assert client.ask("LOCATE,p-7,0").startswith("ERROR,p-7,8,invalid_request,")


def test_a_non_ascii_line_gets_code_8_and_the_connection_goes_on(ur: Any) -> None:
    _, service, client = ur
    assert client.ask("LOCATE,p,1,0.4,-0.1,0.3,0,3.1,0 °".encode()) == "ERROR,-,8,invalid_request,the line is not ASCII"
    assert client.ask(b"\xff\xfe") == "ERROR,-,8,invalid_request,the line is not ASCII"
    assert service.calls == []
    assert client.ask("STATUS").startswith("STATUS,-,0,")


def test_empty_lines_are_ignored(ur: Any) -> None:
    _, _, client = ur
    client.send(b"\n\r\n   \n")
    assert client.ask("STATUS").startswith("STATUS,-,0,")


def test_an_over_long_line_closes_the_connection_and_the_gateway_goes_on(ur: Any) -> None:
    gateway, service, client = ur
    reply = client.ask("LOCATE,p,1," + "1" * 2000)
    assert reply.startswith("ERROR,-,8,invalid_request,line longer than 1024 bytes")
    assert client.read() == ""  # closed
    # an unterminated flood is refused the same way
    flood = Client(gateway.address)
    flood.sock.sendall(b"x" * 5000)
    assert flood.read().startswith("ERROR,-,8,")
    assert flood.read() == ""
    flood.close()
    other = Client(gateway.address)
    assert other.ask("STATUS").startswith("STATUS,-,0,")
    other.close()
    assert [c for c, _ in service.calls] == ["status"]


def test_a_line_split_across_packets_and_a_close_mid_line(ur: Any) -> None:
    gateway, service, client = ur
    client.sock.sendall(b"STA")
    client.sock.sendall(b"TUS,s1")
    assert client.ask("") == "STATUS,s1,0,1,17,412.5,ok,ready"
    half = Client(gateway.address)
    half.sock.sendall(b"LOCATE,p,1,0.4")
    half.close()
    assert client.ask("STATUS,s2").startswith("STATUS,s2,0,")
    assert [d.get("id") for _, d in service.calls] == ["s1", "s2"]


def test_a_handler_that_raises_gets_code_9_and_the_connection_goes_on(ur: Any) -> None:
    _, service, client = ur

    def boom(command: str, doc: dict[str, Any]) -> dict[str, Any]:
        raise RuntimeError("stage detect failed, badly")

    service.respond = boom
    assert client.ask("LOCATE,p9,1") == "ERROR,p9,9,fault,RuntimeError: stage detect failed; badly"
    service.respond = lambda c, d: {"not": "a reply"}
    assert client.ask("LOCATE,p10,1").startswith("ERROR,p10,9,fault,")
    service.respond = FakeService.default
    assert client.ask("LOCATE,p11,1").startswith("LOCATE,p11,0,1,")


def test_too_many_connections_get_busy() -> None:
    with running(max_connections=2) as (gateway, _):
        a, b = Client(gateway.address), Client(gateway.address)
        assert a.ask("STATUS").startswith("STATUS,") and b.ask("STATUS").startswith("STATUS,")
        c = Client(gateway.address)
        assert c.read() == "ERROR,-,7,busy,too many connections (2)"
        assert c.read() == ""
        c.close()
        assert a.ask("STATUS").startswith("STATUS,")
        for client in (a, b):
            client.close()


# -- the allow list -----------------------------------------------------------------------------
ALLOW_TABLE = [
    ("127.0.0.1", [], True),
    ("127.0.0.5", [], True),
    ("::1", [], True),
    ("::ffff:127.0.0.1", [], True),
    ("10.0.0.5", ["10.0.0.0/24"], True),
    ("10.0.0.5", ["10.0.0.5"], True),
    ("::ffff:10.0.0.5", ["10.0.0.0/24"], True),
    ("10.0.0.5", ["10.0.0.1/24"], True),  # strict=False: the host bits are ignored
    ("10.0.1.5", ["10.0.0.0/24"], False),
    ("10.0.0.5", [], False),
    ("192.168.1.20", ["10.0.0.0/24", "fd00::/8"], False),
    ("fd00::7", ["fd00::/8"], True),
    ("fe80::1%eth0", ["fe80::/10"], True),
    ("not-an-ip", ["0.0.0.0/0"], False),
]


@pytest.mark.parametrize(("peer", "allow", "expected"), ALLOW_TABLE)
def test_allowed_table(peer: str, allow: list[str], expected: bool) -> None:
    assert allowed(peer, allow) is expected


@settings(max_examples=50, deadline=None)
@given(st.ip_addresses(v=4))
def test_allowed_is_loopback_or_the_network(ip: Any) -> None:
    assert allowed(str(ip), ["10.0.0.0/24"]) is (ip.is_loopback or ip in ipaddress.ip_network("10.0.0.0/24"))
    assert allowed(str(ip), []) is ip.is_loopback


def test_a_peer_outside_the_allow_list_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(tcp_gateway, "allowed", lambda peer, allow: False)
    with running() as (gateway, service):
        client = Client(gateway.address)
        line = "ERROR,-,8,invalid_request,connection from 127.0.0.1 refused: not in the gateway's allow list"
        assert client.read() == line
        assert client.read() == ""
        client.close()
    assert service.calls == []


def test_listening_beyond_loopback_needs_an_allow_list() -> None:
    gateway = TcpGateway(FakeService(), GatewaySettings(listen="0.0.0.0:0"))
    with pytest.raises(ValueError, match=r"listening on 0\.0\.0\.0 needs an allow list"):
        gateway.start()
    with pytest.raises(ValueError, match="needs an allow list"):
        start_gateway(FakeService(), {"listen": "192.168.10.3:0"})


def test_settings_errors_are_readable_value_errors() -> None:
    with pytest.raises(ValueError, match="max_connections"):
        start_gateway(FakeService(), {"listen": "127.0.0.1:0", "max_connections": 0})
    with pytest.raises(ValueError, match="speed"):
        start_gateway(FakeService(), {"speed": 3})
    with pytest.raises(ValueError, match="not an IP address or network"):
        start_gateway(FakeService(), {"allow": ["robot-7"]})
    with pytest.raises(ValueError, match="host:port"):
        start_gateway(FakeService(), {"listen": "127.0.0.1"})
    with pytest.raises(ValueError, match="format"):
        start_gateway(FakeService(), {"format": "fanuc"})


def test_a_port_in_use_is_a_value_error() -> None:
    with running() as (gateway, _):
        port = gateway.address[1]
        with pytest.raises(ValueError, match=rf"cannot listen on 127\.0\.0\.1:{port}"):
            start_gateway(FakeService(), {"listen": f"127.0.0.1:{port}"})


def test_start_gateway_serves() -> None:
    gateway = start_gateway(FakeService(), {"listen": "127.0.0.1:0", "format": "kuka"})
    try:
        assert gateway.address[0] == "127.0.0.1" and gateway.address[1] > 0
        client = Client(gateway.address)
        assert client.ask("STATUS").startswith("STATUS,-,0,")
        client.close()
    finally:
        gateway.close()


def test_close_returns_with_a_client_still_connected() -> None:
    with running() as (gateway, _):
        client = Client(gateway.address)
        assert client.ask("STATUS").startswith("STATUS,")
        closer = threading.Thread(target=gateway.close)
        closer.start()
        closer.join(TIMEOUT_S)
        assert not closer.is_alive()
        assert client.read() == ""  # the gateway closed the connection
        client.close()
        assert not any(t.name.startswith("vgr-gateway") for t in threading.enumerate())
        with pytest.raises(OSError):
            Client(gateway.address)


# -- bad input never crashes the gateway -----------------------------------------------------
PRINTABLE = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=300)
LINES = st.one_of(
    PRINTABLE,
    st.builds(lambda c, rest: f"{c},{rest}", st.sampled_from(["LOCATE", "guide", "STATUS", "Locate"]), PRINTABLE),
    st.builds(
        lambda c, n, xs: ",".join([c, "p", n, *xs]),
        st.sampled_from(["LOCATE", "GUIDE"]),
        st.sampled_from(["0", "1", "-1", "2", "x"]),
        st.lists(st.one_of(st.floats().map(repr), st.sampled_from(["nan", "1e999", "", " 1 "])), max_size=14),
    ),
)


def test_printable_lines_always_get_exactly_one_reply_line() -> None:
    with running() as (gateway, _):
        client = Client(gateway.address)

        @settings(max_examples=50, deadline=None)
        @given(LINES)
        def one_reply(line: str) -> None:
            assume(line.strip())
            reply = client.ask(line)
            assert reply.split(",")[0] in ("LOCATE", "GUIDE", "STATUS", "ERROR"), reply
            assert reply.split(",")[2].isdigit()
            assert client.ask("STATUS,sync") == "STATUS,sync,0,1,17,412.5,ok,ready"  # nothing else was pending

        one_reply()
        client.close()
