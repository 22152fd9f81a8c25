"""The cell service end to end: `vgr serve` of the simulated cell in a child process, driven over its
API (engine.run.cell.client), its TCP gateway and the simulated devices' stage services (as the
simulated robot program plugins.sim.cell_controller does).

Each status code from a real cause, reload between cycles, a camera fault and its recovery, repeated
request ids, SIGTERM mid-cycle (within and beyond the stop grace), the TCP gateway, an unauthorised
controller, replay of the rolling cycle files, and the camera in a process of its own. One server is
shared by the tests that can share it; stop, SIGTERM, security and the two-process cell have their own.
"""

from __future__ import annotations

import contextlib
import json
import secrets
import shutil
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from service_helpers import (
    Server,
    camera_fault,
    child_env,
    place,
    private_runtime_dir,
    reply_validator,
    vgr,
    wait_for,
    write_recipe,
)

from engine.recording.reader import load
from engine.recording.replay import replay
from engine.run.cell.client import CellClient, CellUnreachableError
from engine.run.cell.codes import Status
from engine.run.cell.protocol import pose_doc, pose_from_doc
from engine.transforms import T_from_Rt
from plugins.sim.cell_controller import PART_POSE, PHOTO_POSE, SimController
from plugins.vendor_poses import ur_from_T

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(240)]

VALIDATOR = reply_validator()
FLIPPED = PART_POSE @ T_from_Rt(Rotation.from_euler("x", 180, degrees=True).as_matrix(), (0.0, 0.0, 0.0))
GRACE_S = 5.0  # engine.run.cell.service.STOP_GRACE_S


def shifted(dx_m: float) -> np.ndarray:
    """The part's nominal pose moved by *dx_m* along the world's x."""
    return T_from_Rt(np.eye(3), (dx_m, 0.0, 0.0)) @ PART_POSE


def unique_cell(prefix: str) -> str:
    return f"{prefix}{secrets.token_hex(3)}"


def check(reply: dict[str, Any], status: str, *, cycle: int | None = None) -> dict[str, Any]:
    """*reply* has *status* with its number from engine.run.cell.codes and is a valid reply document."""
    assert reply["status"] == status, reply
    assert reply["code"] == int(Status[status]), reply
    if VALIDATOR is not None:
        VALIDATOR.validate(reply)
    if cycle is not None:
        assert reply["cycle"] == cycle, reply
    return reply


class Later:
    """*fn* run in a thread: its value (or exception) once it ends."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.value: Any = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, args=(fn,), daemon=True)
        self.thread.start()

    def _run(self, fn: Callable[[], Any]) -> None:
        try:
            self.value = fn()
        except BaseException as exc:  # (handed to the test)
            self.error = exc

    def done(self) -> bool:
        return not self.thread.is_alive()

    def result(self, timeout_s: float = 60.0) -> Any:
        self.thread.join(timeout_s)
        assert not self.thread.is_alive(), f"no answer within {timeout_s:g} s"
        if self.error is not None:
            raise self.error
        return self.value


@dataclass
class Cell:
    server: Server
    client: CellClient
    sim: SimController

    def status(self) -> dict[str, Any]:
        return check(self.client.status(), "ok")["result"]

    def locate(self, **kw: Any) -> dict[str, Any]:
        """A locate from the photo pose (where the robot is)."""
        return self.client.locate(PHOTO_POSE, **kw)

    def reload(self, changes: dict[str, Any], status: str = "ok") -> dict[str, Any]:
        return check(self.client.reload(changes), status)

    def wait_cycle_started(self, number: int) -> None:
        wait_for(f"cycle {number} under way", lambda: self.status()["cycles"] >= number, 30.0)


def served(server: Server) -> Cell:
    """The cell of *server* once it serves, the robot at the photo pose, the part at its nominal pose."""
    client = server.wait_ready()
    sim = SimController(client)
    sim._move(PHOTO_POSE, "move_j")
    place(sim, PART_POSE)
    return Cell(server, client, sim)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    """The shared server: the simulated cell with a TCP gateway on a free port."""
    folder = tmp_path_factory.mktemp("cell")
    runtime = private_runtime_dir()
    name = unique_cell("shared")
    recipe = write_recipe(folder, name, serve={"gateways": {"tcp": {"listen": "127.0.0.1:0", "format": "ur"}}})
    server = Server(recipe, name, folder, runtime)
    client = None
    try:
        c = served(server)
        client = c.client
        yield c
    finally:
        if client is not None:
            client.close()
        try:
            server.stop(signal.SIGINT, 30.0)
        finally:
            server.kill()
            shutil.rmtree(runtime, ignore_errors=True)


@pytest.fixture
def nominal(cell: Cell) -> Iterator[Cell]:
    """The shared cell, its part put back at the nominal pose after the test."""
    yield cell
    place(cell.sim, PART_POSE)


@pytest.fixture
def own_server(tmp_path: Path) -> Iterator[Callable[..., Server]]:
    """Start servers of a test's own (each killed at the end of the test)."""
    runtime = private_runtime_dir()
    started: list[Server] = []

    def start(name: str, *extra: str, serve: dict[str, Any] | None = None, **kw: Any) -> Server:
        recipe = write_recipe(tmp_path, name, serve=serve)
        server = Server(recipe, name, tmp_path, runtime, *extra, **kw)
        started.append(server)
        return server

    try:
        yield start
    finally:
        for server in started:
            server.kill()
        shutil.rmtree(runtime, ignore_errors=True)


def cycle_file(server: Server, cycle: int, request_id: str, timeout_s: float = 30.0) -> Path:
    """The finished cycle file of cycle *cycle* (request *request_id*): ``cycle-<n>.mcap`` or, when a
    reload finished a file before that cycle, ``cycle-<n>-<k>.mcap``."""
    folder = server.run_dir / "cycles"

    def finished() -> Path | None:
        for path in sorted(folder.glob(f"cycle-{cycle:07d}*.mcap")):
            try:
                rec = load(path)
            except Exception:  # (still being written)
                continue
            ids = [c["id"] for c in json_list(rec.metadata.get("vgr.summary", {}).get("cycles", "[]"))]
            if request_id in ids:
                return path
        return None

    return wait_for(f"the cycle file of cycle {cycle}", finished, timeout_s, 0.2)


def captures_of(status: dict[str, Any]) -> int:
    """How many captures the cycles made (the takt figures' count of camera.capture calls)."""
    return int(status["takt_parts_ms"].get("camera.capture", {}).get("n", 0))


def json_list(text: str) -> list[dict[str, Any]]:
    import json

    return list(json.loads(text))


# =========================================================================== 1. each status code
def test_ok_from_the_photo_pose_gives_a_small_correction_and_the_install_target(nominal: Cell) -> None:
    cycles = nominal.status()["cycles"]
    reply = check(nominal.locate(request_id="ok-photo"), "ok", cycle=cycles + 1)
    result = reply["result"]
    assert (result["frame"], result["requested"], result["found"]) == ("base", 1, 1)
    np.testing.assert_allclose(pose_from_doc(result["pose"]), PHOTO_POSE, atol=1e-9)
    [part] = result["parts"]
    assert part["translation_mm"] < 2.0 and part["rotation_deg"] < 0.5, part  # the part is where taught
    assert set(part["targets"]) == {"install"}
    assert reply["timing_ms"]["total"] > 0 and "matcher.match_first" in reply["timing_ms"]
    # and without a pose: the recipe's pose_from_robot takes the simulated robot's (at the photo pose)
    again = check(nominal.client.locate(request_id="ok-robot"), "ok", cycle=cycles + 2)
    np.testing.assert_allclose(pose_from_doc(again["result"]["pose"]), PHOTO_POSE, atol=1e-6)


def test_no_part_when_the_part_lies_upside_down(nominal: Cell) -> None:
    """The wrong side up matches nothing. (A part 2 m away leaves the simulated capture empty, which
    the locator answers camera_fault: a real camera always sees its table, so no points is a camera's fault.)"""
    place(nominal.sim, FLIPPED)
    reply = check(nominal.locate(), "no_part")
    assert reply["message"].startswith("match failed") and reply["result"] == {}


def test_ambiguous_when_the_match_is_less_certain_than_the_matcher_allows(nominal: Cell) -> None:
    """The matcher's rule (plugins/registration/fine.py): a one-sigma of the pose above
    max_sigma_translation_mm is ambiguous. (matcher.ambiguity_gap = 1 changes nothing here: the rule
    needs a distinct runner-up of enough fitness, and this part has none.)"""
    nominal.reload({"matcher.max_sigma_translation_mm": 0.001})
    try:
        reply = check(nominal.locate(), "ambiguous")
    finally:
        nominal.reload({"matcher.max_sigma_translation_mm": 0.2})
    assert "exceeds the limits (0.001 mm" in reply["message"], reply
    check(nominal.locate(), "ok")


def test_out_of_limits_when_the_part_is_further_off_than_the_limit(nominal: Cell) -> None:
    place(nominal.sim, shifted(0.08))  # 80 mm: beyond max_correction_mm 50
    reply = check(nominal.locate(), "out_of_limits")
    assert "install 80.0" in reply["message"] and "exceeds the limit 50.0 mm" in reply["message"], reply
    assert reply["result"]["parts"] == [] and reply["result"]["found"] == 0
    [part] = reply["result"]["rejected"]
    assert 79.0 < part["translation_mm"] < 81.0  # the refused correction is reported, not to be applied


def test_a_bad_start_pose_is_robot_pose_invalid_at_any_step(nominal: Cell) -> None:
    bad = {"xyz_m": [0.0, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 2.0]}
    for step in (0, 1):
        doc = {"id": f"bad-start-{step}", "step": step, "pose": pose_doc(PHOTO_POSE), "start_pose": bad}
        check(nominal.client.call("guide", doc), "robot_pose_invalid")


def test_not_converged_at_the_last_step_with_the_part_off(nominal: Cell) -> None:
    place(nominal.sim, shifted(0.005))
    reply = check(nominal.client.guide(PHOTO_POSE, 5, PHOTO_POSE), "not_converged")
    assert reply["message"].startswith("not converged after 5 moves"), reply
    assert 4.0 < reply["result"]["residual_mm"] < 6.0, reply
    assert "next_pose" not in reply["result"] and "correction" not in reply["result"]


def test_camera_fault_when_the_camera_is_disconnected(nominal: Cell) -> None:
    camera_fault(nominal.sim, kind="disconnect", captures=1)
    reply = check(nominal.locate(), "camera_fault")
    assert "camera disconnected" in reply["message"], reply
    check(nominal.locate(), "ok")


def test_robot_pose_invalid_for_a_quaternion_of_norm_2(nominal: Cell) -> None:
    captures = captures_of(nominal.status())
    bad = {"xyz_m": [-0.49, -0.14, 0.45], "quat_xyzw": [0.0, 0.0, 0.0, 2.0]}
    reply = check(nominal.client.call("locate", {"id": "bad-pose", "pose": bad}), "robot_pose_invalid")
    assert "norm 2.000000" in reply["message"], reply
    assert captures_of(nominal.status()) == captures  # checked before capturing


def test_busy_while_a_cycle_runs(nominal: Cell) -> None:
    cycles = nominal.status()["cycles"]
    camera_fault(nominal.sim, kind="hang", seconds=3.0)
    first = Later(lambda: nominal.locate(request_id="long-cycle"))
    nominal.wait_cycle_started(cycles + 1)
    reply = check(nominal.locate(), "busy", cycle=0)
    assert not first.done(), "busy came after the long cycle, not at once"
    assert f"cycle {cycles + 1} (locate long-cycle)" in reply["message"], reply
    check(first.result(), "ok", cycle=cycles + 1)
    assert nominal.status()["cycles"] == cycles + 1  # busy ran no cycle


def test_invalid_request_for_bad_json_a_bad_id_and_a_bad_count(nominal: Cell) -> None:
    lines = len(nominal.server.cycle_lines())
    reply = check(nominal.client.call_raw("locate", b'{"id": "x", '), "invalid_request", cycle=0)
    assert "not JSON" in reply["message"] and reply["id"] is None
    check(nominal.client.call_raw("locate", b'{"id": "not an id!"}'), "invalid_request", cycle=0)
    check(nominal.client.call_raw("locate", b'{"api": 2, "id": "v2"}'), "invalid_request", cycle=0)
    assert len(nominal.server.cycle_lines()) == lines  # refused before any cycle
    reply = check(nominal.client.call("locate", {"id": "bad-count", "count": 0}), "invalid_request")
    assert "count must be an integer from 1 to 8, got 0" in reply["message"]
    reply = check(nominal.client.call("locate", {"id": "text-count", "count": "2"}), "invalid_request")
    assert "got '2'" in reply["message"]


def test_fault_when_a_cycle_exceeds_the_cycle_timeout_and_stopping_after_a_stop(own_server: Any) -> None:
    """serve.cycle_timeout_s 2.5 s and a camera hanging 4 s: fault. Then a stop request while a cycle
    runs: later requests are answered stopping, no cycle starts, the service ends in order (exit 0)."""
    server = own_server(unique_cell("stop"), serve={"cycle_timeout_s": 2.5})
    c = served(server)
    camera_fault(c.sim, kind="hang", seconds=4.0)
    reply = check(c.locate(request_id="too-slow"), "fault", cycle=1)
    assert "no reply within 2.5 s (serve.cycle_timeout_s)" in reply["message"], reply
    assert c.status()["last_error"]["status"] == "fault"
    place(c.sim, PART_POSE)  # (waits for the camera's hang to end: a stage handles one request at a time)

    camera_fault(c.sim, kind="hang", seconds=2.0)
    running = Later(lambda: c.locate(request_id="under-way"))
    c.wait_cycle_started(2)
    check(c.client.stop(), "ok")
    check(c.locate(request_id="after-stop"), "stopping", cycle=0)
    assert running.result()["status"] in ("ok", "fault")
    assert server.wait(30.0) == 0, server.output()
    assert [line["id"] for line in server.cycle_lines()] == ["too-slow", "under-way"]
    assert "2 cycle(s) served" in server.out() and "a stop request" in server.out(), server.output()


# =========================================================================== 2. reload
def test_reload_takes_effect_on_the_next_cycle_and_a_bad_one_changes_nothing(nominal: Cell) -> None:
    before = nominal.status()["reloads"]
    reply = nominal.reload({"locator.max_correction_mm": 0.001})
    assert reply["result"] == {"reloads": before + 1} and "locator rebuilt" in reply["message"]
    try:
        refused = check(nominal.locate(request_id="after-reload"), "out_of_limits")
        assert "exceeds the limit 0.001 mm" in refused["message"], refused
        path = cycle_file(nominal.server, refused["cycle"], "after-reload")
        assert "locator.max_correction_mm=0.001" in load(path).overrides
        report, _, _ = replay(path)
        assert report.outcome == "ok", [(v.topic, v.verdict, v.first_difference) for v in report.requests]
    finally:
        nominal.reload({"locator.max_correction_mm": 50})
    check(nominal.locate(), "ok")
    assert nominal.status()["reloads"] == before + 2

    unknown = nominal.reload({"locator.no_such_param": 1}, "invalid_request")
    assert unknown["message"].startswith("nothing reloaded") and "no_such_param" in unknown["message"]
    missing = nominal.reload({"locator.template": "/nonexistent/part.vgrtpl"}, "invalid_request")
    assert "nothing reloaded" in missing["message"] and "/nonexistent/part.vgrtpl" in missing["message"]
    nominal.reload({"locator": 1}, "invalid_request")
    assert nominal.status()["reloads"] == before + 2
    check(nominal.locate(), "ok")


# =========================================================================== 3. camera fault, recovery
def test_two_captures_lost_then_the_camera_is_back(nominal: Cell) -> None:
    faults = nominal.status()["by_status"].get("camera_fault", 0)
    camera_fault(nominal.sim, kind="disconnect", captures=2)
    first = check(nominal.locate(request_id="lost-1"), "camera_fault")
    second = check(nominal.locate(request_id="lost-2"), "camera_fault")
    check(nominal.locate(request_id="back"), "ok", cycle=second["cycle"] + 1)
    assert second["cycle"] == first["cycle"] + 1
    assert nominal.server.proc.poll() is None
    status = nominal.status()
    assert status["ready"] is True and status["state"] == "serving"
    assert status["by_status"]["camera_fault"] == faults + 2
    last = status["last_error"]
    assert (last["cycle"], last["id"], last["status"]) == (second["cycle"], "lost-2", "camera_fault")
    assert "camera disconnected (simulated fault)" in last["message"]


# =========================================================================== 4. repeated ids
def test_a_repeated_id_gets_the_same_reply_without_a_second_capture(nominal: Cell) -> None:
    status = nominal.status()
    cycles, captures = status["cycles"], captures_of(status)
    lines = len(nominal.server.cycle_lines())
    first = check(nominal.locate(request_id="part-0017"), "ok", cycle=cycles + 1)
    place(nominal.sim, shifted(0.004))  # a second capture would see the part 4 mm further
    again = nominal.locate(request_id="part-0017")
    assert again == first
    status = nominal.status()
    assert status["cycles"] == cycles + 1
    assert captures_of(status) == captures + 1
    assert [line["id"] for line in nominal.server.cycle_lines()[lines:]] == ["part-0017"]
    other = check(nominal.client.call("guide", {"id": "part-0017", "step": 0}), "invalid_request", cycle=0)
    assert "was a locate request" in other["message"]
    assert nominal.status()["cycles"] == cycles + 1


def test_a_repeat_while_its_cycle_runs_waits_and_others_are_still_busy_at_once(nominal: Cell) -> None:
    """The repeat waits for its first request's cycle; meanwhile a new request is answered busy at
    once, not queued behind the repeat."""
    cycles = nominal.status()["cycles"]
    camera_fault(nominal.sim, kind="hang", seconds=3.0)
    first = Later(lambda: nominal.locate(request_id="slow-part"))
    nominal.wait_cycle_started(cycles + 1)
    repeat = Later(lambda: nominal.locate(request_id="slow-part"))
    time.sleep(0.3)  # the repeat is in (and waits)
    other = Later(lambda: nominal.locate(request_id="meanwhile"))
    reply = other.result(30.0)
    assert not first.done(), f"the other request was answered only after the cycle: {reply}"
    check(reply, "busy", cycle=0)
    one = check(first.result(), "ok", cycle=cycles + 1)
    assert repeat.result() == one
    assert nominal.status()["cycles"] == cycles + 1


# =========================================================================== 5. SIGTERM
def test_sigterm_mid_cycle_lets_the_cycle_finish_and_starts_no_other(own_server: Any) -> None:
    server = own_server(unique_cell("term"))
    c = served(server)
    check(c.locate(request_id="before"), "ok", cycle=1)
    camera_fault(c.sim, kind="hang", seconds=3.0)
    in_flight = Later(lambda: c.locate(request_id="in-flight"))
    c.wait_cycle_started(2)
    time.sleep(0.5)
    server.send(signal.SIGTERM)
    try:
        late = c.locate(request_id="after-signal")
        check(late, "stopping", cycle=0)
    except CellUnreachableError:
        pass  # (the service may already be gone)
    reply = in_flight.result(30.0)
    check(reply, "ok", cycle=2)
    assert server.wait(30.0) == 0, server.output()
    assert [line["id"] for line in server.cycle_lines()] == ["before", "in-flight"]
    assert "2 cycle(s) served" in server.out() and "SIGTERM" in server.out(), server.output()
    assert "Traceback" not in server.output()


def test_joint_angles_instead_of_the_pose_give_the_same_correction(nominal: Cell) -> None:
    from engine.messages import Request

    state = nominal.sim._device("robot", "state", Request(command="state"))
    by_pose = check(nominal.client.locate(state.T, request_id="by-pose"), "ok")["result"]
    by_joints = check(
        nominal.client.call("locate", {"id": "by-joints", "joints_rad": [float(v) for v in state.joints]}), "ok"
    )["result"]
    np.testing.assert_allclose(by_joints["pose"]["xyz_m"], by_pose["pose"]["xyz_m"], atol=1e-9)
    # (two captures: their noise moves the match by a few hundredths of a millimetre)
    assert by_joints["parts"][0]["translation_mm"] == pytest.approx(by_pose["parts"][0]["translation_mm"], abs=0.1)
    bad = nominal.client.call("locate", {"id": "bad-joints", "joints_rad": [0.0, 1.0]})
    check(bad, "robot_pose_invalid")
    assert "6 finite angles" in bad["message"]


TWO_PARTS = (
    "camera.parts=[{name: part, workpiece: feature_part, pose: {xyz_m: [-0.49, -0.08, 0.0], rpy_deg: [0, 0, 10]}}, "
    "{name: part2, workpiece: feature_part, pose: {xyz_m: [-0.46, -0.16, 0.0], rpy_deg: [0, 0, 40]}}]"
)


def test_several_parts_in_one_capture_the_ones_beyond_the_limits_rejected(own_server: Any) -> None:
    """Two parts in view: the one at the taught place is usable; the other, turned 30 deg further, is
    found but beyond the limits (50 mm / 15 deg): listed as rejected, never as a part to use."""
    server = own_server(unique_cell("two"), "-p", TWO_PARTS)
    c = served(server)
    reply = check(c.locate(count=2, request_id="two-parts"), "ok")
    result = reply["result"]
    assert (result["requested"], result["found"], len(result["parts"]), len(result["rejected"])) == (2, 1, 1, 1)
    assert result["parts"][0]["translation_mm"] < 1.0
    assert "exceeds the limit" in result["rejected"][0]["refused"]
    assert result["rejected"][0]["rotation_deg"] == pytest.approx(30.0, abs=0.5)
    one = check(c.locate(count=1, request_id="one-part"), "ok")["result"]
    assert one["found"] == 1 and one["rejected"] == []


def test_a_second_stop_signal_stops_at_once_exit_130(own_server: Any) -> None:
    server = own_server(unique_cell("twice"))
    c = served(server)
    camera_fault(c.sim, kind="hang", seconds=GRACE_S + 3.0)
    in_flight = Later(lambda: c.locate(request_id="long"))
    c.wait_cycle_started(1)
    server.send(signal.SIGINT)
    wait_for("the service stopping", lambda: c.client.status()["result"]["state"] == "stopping", 10.0)
    server.send(signal.SIGINT)
    assert server.wait(40.0) == 130, server.output()
    assert "second stop signal" in " ".join(server.out().split()), server.output()
    with contextlib.suppress(CellUnreachableError):
        assert in_flight.result(30.0)["status"] in ("stopping", "fault")


def test_serve_json_is_one_document_of_its_schema(own_server: Any) -> None:
    import jsonschema

    from engine.cli.json_output import schema

    server = own_server(unique_cell("json"), "--json")
    c = served(server)
    check(c.locate(request_id="only"), "ok", cycle=1)
    place(c.sim, shifted(0.08))  # a part refused (its alarm) is that cycle's answer, not the service's outcome
    check(c.locate(request_id="too-far"), "out_of_limits", cycle=2)
    assert server.stop(signal.SIGINT) == 0, server.output()
    doc = json.loads(server.out().strip().splitlines()[-1])
    jsonschema.validate(doc, schema("serve"))
    counts = {"ok": 1, "out_of_limits": 1}
    assert (doc["exit_code"], doc["outcome"], doc["cycles"], doc["by_status"]) == (0, "ok", 2, counts)


def test_sigterm_with_a_cycle_longer_than_the_grace_cuts_it_short_exit_130(own_server: Any) -> None:
    server = own_server(unique_cell("cut"))
    c = served(server)
    camera_fault(c.sim, kind="hang", seconds=GRACE_S + 3.0)
    in_flight = Later(lambda: c.locate(request_id="too-long"))
    c.wait_cycle_started(1)
    time.sleep(0.5)
    server.send(signal.SIGTERM)
    code = server.wait(40.0)
    assert code == 130, server.output()
    assert "1 cycle(s) served (1 stopping)" in server.out(), server.output()
    assert "interrupted (SIGTERM): cycle 1 cut short after 5 s" in " ".join(server.out().split()), server.output()
    try:
        reply = in_flight.result(30.0)
        assert reply["status"] in ("stopping", "fault"), reply
    except CellUnreachableError:
        pass  # the service ended before it could answer
    assert [(line["id"], line["status"]) for line in server.cycle_lines()] == [("too-long", "stopping")]


# =========================================================================== 6. TCP gateway
class LineClient:
    def __init__(self, address: tuple[str, int]) -> None:
        self.sock = socket.create_connection(address, timeout=60.0)
        self.file = self.sock.makefile("rb")

    def ask(self, line: str) -> str:
        self.sock.sendall(line.encode() + b"\n")
        return self.file.readline(64 * 1024).decode("ascii").removesuffix("\n")

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def test_the_tcp_gateway_answers_locate_lines_of_a_real_service(nominal: Cell) -> None:
    address = nominal.server.gateway_address("tcp")
    client = LineClient(address)
    try:
        line = client.ask("LOCATE,gw-1,1")
        fields = line.split(",")
        assert fields[:4] == ["LOCATE", "gw-1", "0", "1"], line
        values = [float(v) for v in fields[4:10]]
        assert fields[10] == "ok" and fields[11].startswith("located the part"), line
        assert len(fields) == 12
        bad = client.ask("LOCATE,gw-2")
        assert bad.startswith("ERROR,") and bad.split(",")[2:4] == ["8", "invalid_request"], bad
        assert client.ask("LOCATE,gw-3,1").startswith("LOCATE,gw-3,0,1,")
        assert client.ask("LOCATE,gw-1,1") == line  # the same id: the same reply
    finally:
        client.close()
    # the same request over the API (a repeat): its correction is the line's, in UR format
    reply = check(nominal.client.locate(request_id="gw-1"), "ok")
    correction = pose_from_doc(reply["result"]["parts"][0]["correction"])
    np.testing.assert_allclose(values, ur_from_T(correction), rtol=1e-8, atol=1e-12)


# =========================================================================== 7. security
@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """A cell with a security: block (mTLS and the access list) on tls/127.0.0.1, and its certificates:
    a controller's ("controller"), an observer's ("viewer"), and one of another CA named like the process."""
    from process_helpers import free_port

    from engine.security.certs import Identity, write_bundle

    folder = tmp_path_factory.mktemp("secured")
    runtime = private_runtime_dir()
    name = unique_cell("sec")
    endpoint = f"tls/127.0.0.1:{free_port()}"
    security = {"certs": "certs", "observers": ["viewer"], "controllers": ["controller"]}
    top = {"security": security, "processes": {"main": {"listen": [endpoint]}}}
    recipe = write_recipe(folder, name, top=top)
    made = subprocess.run(
        vgr("certs", "make", str(recipe), "--out", str(folder / "certs")),
        env=child_env(runtime),
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert made.returncode == 0, made.stdout + made.stderr
    other = folder / "other"  # another CA's certificate named like the process; trusting the cell's CA
    write_bundle(other, [Identity("main")], ca_name="another CA")
    (other / "ca.pem").write_bytes((folder / "certs" / "ca.pem").read_bytes())
    server = Server(recipe, name, folder, runtime)
    try:
        wait_for("the secured cell ready", lambda: "ready" in server.err() or server.proc.poll() is not None, 60.0)
        assert server.proc.poll() is None, server.output()
        yield {"server": server, "endpoint": endpoint, "certs": folder / "certs", "other": other}
    finally:
        server.kill()
        shutil.rmtree(runtime, ignore_errors=True)


def test_a_secured_cell_refuses_controllers_without_its_certificates(secured: dict[str, Any]) -> None:
    server, endpoint = secured["server"], secured["endpoint"]
    tries: dict[str, dict[str, Any]] = {
        "plain tcp": {"connect": [endpoint.replace("tls/", "tcp/")]},
        "tls without a certificate": {"connect": [endpoint]},
        "another CA's certificate": {"connect": [endpoint], "certs": str(secured["other"]), "identity": "main"},
    }
    for what, kw in tries.items():
        with pytest.raises(CellUnreachableError):
            client = CellClient(server.cell, connect_timeout_s=3.0, timeout_s=3.0, **kw)
            try:  # (should it connect at all, its request must not be served)
                client.locate(request_id=f"intruder-{what.replace(' ', '-').replace(chr(39), '')}")
            finally:
                client.close()
    # an observer of the run is let in and sees the cell serving, but may not call it
    observer = CellClient(
        server.cell, connect=[endpoint], certs=str(secured["certs"]), identity="viewer", connect_timeout_s=10.0
    )
    try:
        with pytest.raises(CellUnreachableError):
            observer.locate(request_id="observer-may-not-call")
    finally:
        observer.close()
    assert server.proc.poll() is None
    assert server.cycle_lines() == []  # no cycle ran


def test_a_secured_cell_serves_a_controller_with_a_certificate_of_its_ca(secured: dict[str, Any]) -> None:
    server = secured["server"]
    client = CellClient(
        server.cell,
        connect=[secured["endpoint"]],
        certs=str(secured["certs"]),
        identity="controller",
        connect_timeout_s=5.0,
        timeout_s=10.0,
    )
    try:
        check(client.locate(PHOTO_POSE, request_id="admitted"), "ok")
    finally:
        client.close()


# =========================================================================== 8. replay
def test_three_cycle_files_replay_with_identical_replies(nominal: Cell) -> None:
    paths = []
    for k in range(3):
        if k:
            place(nominal.sim, shifted(0.002 * k))
        reply = check(nominal.locate(request_id=f"replayed-{k}"), "ok")
        paths.append(cycle_file(nominal.server, reply["cycle"], f"replayed-{k}"))
    for path in paths:
        report, _, _ = replay(path)
        assert report.outcome == "ok", [(v.topic, v.verdict, v.first_difference) for v in report.requests]
        replies = [v for v in report.requests if v.topic.endswith("(replies)")]
        assert any(v.verdict == "identical" and v.recorded >= 1 for v in replies), report.requests
        assert any("/locator/srv/locate <- _cell" in v.topic for v in replies), [v.topic for v in replies]


# =========================================================================== 9. two processes
def test_the_camera_in_a_process_of_its_own(own_server: Any) -> None:
    """The service and its camera in two processes: a locate is ok; SIGINT to the service ends it in
    order (exit 0) and the camera's process follows it (exit 0, its run finished, not interrupted).
    (SIGINT to the camera's process itself interrupts that process: exit 130, as any member of a run.)"""
    name = unique_cell("two")
    main = own_server(name, "-p", "vars.camera_process=cam")
    cam = own_server(name, "-p", "vars.camera_process=cam", process="cam")
    c = served(main)
    reply = check(c.locate(request_id="two-processes"), "ok", cycle=1)
    assert reply["result"]["parts"][0]["translation_mm"] < 2.0
    assert "camera.capture" in reply["timing_ms"]
    c.client.close()
    main.send(signal.SIGINT)
    assert main.wait(60.0) == 0, main.output()
    assert cam.wait(60.0) == 0, cam.output()
    assert "1 cycle(s) served" in main.out()
    assert "run finished" in cam.out(), cam.output()
