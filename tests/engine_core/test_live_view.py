"""``vgr run --view`` and ``vgr replay --view``: a WebSocket client speaking Foxglove's ws-protocol
(advertise, subscribe, binary messageData opcode 1) subscribes to a point-cloud channel and decodes a
message with the schema the channel advertised.

The client offers both subprotocol names, ``foxglove.websocket.v1`` and ``foxglove.sdk.v1`` (either
alone is served too: test_view_protocol_names.py); the messages are those of the ws-protocol spec."""

from __future__ import annotations

import base64
import json
import signal
import socket
import struct
import subprocess
import time

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from process_helpers import ROOT, demo_streaming, env, free_port, vgr
from websockets.sync.client import connect

from engine.recording.reader import load

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]
DEMO = ROOT / "recordings" / "demo.mcap"
MESSAGE_DATA = 1  # binary opcode of ws-protocol
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def connect_when_up(port: int, proc: subprocess.Popen[str], timeout_s: float = 60.0):
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, open_timeout=2)
        except OSError:
            assert proc.poll() is None and time.monotonic() < deadline, "the live view did not come up"
            time.sleep(0.1)


def first_cloud(port: int, proc: subprocess.Popen[str], topic: str) -> tuple[dict, object, bytes]:
    """Connect, subscribe to *topic*, return its advertised channel, the first message decoded and its bytes."""
    with connect_when_up(port, proc) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        channel = None
        while channel is None:
            msg = json.loads(ws.recv(timeout=30))
            if msg["op"] == "advertise":
                channel = next((c for c in msg["channels"] if c["topic"] == topic), None)
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channel["id"]}]}))
        while True:
            frame = ws.recv(timeout=30)
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                break
        opcode, sub_id, log_time = struct.unpack_from("<BIQ", frame)
        assert (opcode, sub_id) == (MESSAGE_DATA, 7) and log_time > 0
    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"])).file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))
    return channel, cls.FromString(frame[13:]), frame[13:]


def stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
    proc.wait(30)


def test_run_view_serves_a_point_cloud_channel(tmp_path):
    port = free_port()
    argv = vgr(*demo_streaming(20, 400, 300), "--no-record", "--runs-dir", str(tmp_path), "--view", str(port))
    proc = subprocess.Popen(argv, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        channel, cloud, _ = first_cloud(port, proc, "/move/cloud")
    finally:
        stop(proc)
    assert (channel["encoding"], channel["schemaName"], channel["schemaEncoding"]) == (
        "protobuf",
        "foxglove.PointCloud",
        "protobuf",
    )
    assert cloud.frame_id == "world" and cloud.point_stride == 12
    assert len(cloud.data) == 300 * 12 and [f.name for f in cloud.fields] == ["x", "y", "z"]
    z = struct.unpack_from("<f", cloud.data, 8)[0]
    assert 0.4 < z < 0.6  # the demo moves the box 0.5 m along z


def test_replay_view_serves_the_recorded_clouds(tmp_path):
    port = free_port()
    argv = vgr("replay", str(DEMO), "--speed", "0.1", "--runs-dir", str(tmp_path), "--view", str(port))
    proc = subprocess.Popen(argv, env=env(), stdout=subprocess.PIPE, text=True)
    try:
        _, cloud, payload = first_cloud(port, proc, "/source/cloud")  # played back from the file
        assert proc.wait(60) == 0  # the replay itself is unchanged: every output identical
    finally:
        stop(proc)
    recorded = {m.payload for m in load(DEMO).messages("/source/cloud")}
    assert payload in recorded and cloud.frame_id == "world" and len(cloud.data) == 400 * cloud.point_stride


def test_a_taken_port_is_refused_before_the_run_makes_its_folder(tmp_path, capsys):
    from engine.cli.main import main

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(["run", str(ROOT / "recipes/demo.yaml"), "--view", str(port), "--runs-dir", str(tmp_path)])
    assert code == 2 and "cannot serve the live view on 127.0.0.1" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_view_hold_serves_each_topics_last_message_after_the_run_until_ctrl_c(tmp_path):
    """A run on the simulated clock is over in about a second; with --view-hold a viewer that
    connects afterwards still gets the last cloud (re-sent when it subscribes), and Ctrl-C ends the
    command with the run's own exit code."""
    port = free_port()
    argv = vgr("run", str(ROOT / "recipes/demo.yaml"), "--no-progress", "--runs-dir", str(tmp_path))
    argv += ["--view", str(port), "--view-hold"]
    proc = subprocess.Popen(argv, env=env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        while not any("live view: the end" in line for line in lines):
            line = proc.stdout.readline()
            assert line, "".join(lines)  # the command ended instead of holding the view
            lines.append(line)
        _, cloud, payload = first_cloud(port, proc, "/move/cloud")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
    finally:
        stop(proc)
    recording = next(tmp_path.glob("*/demo.mcap"))
    assert payload == load(recording).messages("/move/cloud")[-1].payload  # the run's last cloud
    assert cloud.frame_id == "world"


def test_a_short_run_says_how_to_keep_the_view(tmp_path):
    port = free_port()
    argv = vgr("run", str(ROOT / "recipes/demo.yaml"), "--no-progress", "--no-record", "--runs-dir", str(tmp_path))
    done = subprocess.run([*argv, "--view", str(port)], env=env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    said = " ".join((done.stdout + done.stderr).split())
    assert "closed with the end" in said and "--view-hold keeps each topic's last message on view" in said
