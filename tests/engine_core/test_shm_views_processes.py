"""Large payloads as views of the sender's shared memory between real processes
(engine.transport.shm_views): a recorded run whose producer fills loaned arrays and whose consumer
keeps clouds, and the replay of its recording, a full pool, the same recipe across two network namespaces (treated as two hosts: bytes
through the network), and a sender or a receiver killed mid-stream.
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from process_helpers import env as base_env
from process_helpers import free_port, vgr
from view_child import CONSUMERS, payload
from view_stages import cloud_points

from engine.messages import PointCloud, codec
from engine.messages.codec import Kind
from engine.recipe.model import ZenohSettings
from engine.recording.reader import load
from engine.transport.bus import Bus
from engine.transport.shm_views import ViewPool, ViewReader
from engine.transport.wire import WireSender

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(180)]

HERE = Path(__file__).resolve().parent
POINTS = 50_000  # 1.2 MB of float64 points

RECIPE = """
name: views
plugins: [view_stages]
processes:
  producer: {{listen: ["tcp/{host}:{port}"]}}
  consumer: {{connect: ["tcp/{host}:{port}"], listen: []}}
stages:
  src:   {{type: t_cloud_source, process: producer, params: {{n: {n}, points: {points}, interval_s: {interval}, loan: {loan}, stats: "{stats}"}}}}
  shift: {{type: t_cloud_shift, process: consumer, inputs: {{cloud: src.cloud}}, params: {{output: "{shift_out}"}}}}
  sink:  {{type: t_view_sink, process: consumer, inputs: {{cloud: src.cloud}}, params: {{output: "{out}", keep: {keep}, delay_s: {delay}}}}}
"""


def env() -> dict[str, str]:
    return dict(base_env(), VGR_PLUGIN_PATH=str(HERE))


def write_recipe(
    tmp: Path,
    *,
    n: int = 6,
    interval: float = 0.005,
    keep: int = 0,
    delay: float = 0.0,
    host: str = "127.0.0.1",
    loan: bool = False,
) -> Path:
    recipe = tmp / "views.yaml"
    text = RECIPE.format(
        host=host, port=free_port(), n=n, points=POINTS, interval=interval, keep=keep, delay=delay,
        out=tmp / "views.json", shift_out=tmp / "shift.json", loan=str(loan).lower(), stats=tmp / "pool.json",
    )  # fmt: skip
    recipe.write_text(text)
    return recipe


def run_pair(recipe: Path, *extra: str, prefix: tuple[list[str], list[str]] = ([], [])) -> tuple[str, str]:
    """Both processes of *recipe* (consumer first), each under its *prefix* command; their output."""
    procs = []
    for process, pre in zip(("consumer", "producer"), prefix, strict=True):
        cmd = [*pre, *vgr("run", str(recipe), "--process", process, "--no-progress", *extra)]
        procs.append(
            subprocess.Popen(
                cmd, env=env(), cwd=recipe.parent, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
            )
        )
    outs = [p.communicate(timeout=150)[0] for p in procs]
    for p, out in zip(procs, outs, strict=True):
        assert p.returncode == 0, out
    return outs[0], outs[1]


def expected(n: int) -> list[str]:
    return [hashlib.sha256(cloud_points(i, POINTS).tobytes()).hexdigest() for i in range(n)]


def test_clouds_reach_the_consumer_as_read_only_views_kept_ones_stay_intact_and_replay_is_identical(tmp_path):
    recipe = write_recipe(tmp_path, n=12, keep=3, loan=True)
    run_pair(recipe)  # recorded: each side's recorder is handed the views' bytes
    assert json.loads((tmp_path / "pool.json").read_text()) == {"loaned_sent": 12, "shared": 12}  # no copy sent
    got = json.loads((tmp_path / "views.json").read_text())
    rows = got["rows"]
    assert [r["seq"] for r in rows] == list(range(1, 13)) and [r["sha"] for r in rows] == expected(12)
    assert all(r["view"] and not r["writeable"] for r in rows)  # no copy on receive, never written through
    assert got["kept_intact"] == [True, True, True]  # kept past the handler, 9 messages later: unchanged
    assert all(json.loads((tmp_path / "shift.json").read_text()))
    # the producer recorded its loaned clouds from views of their blocks: the bytes each side recorded agree
    sent = load(next(tmp_path.glob("runs/*-producer/*.mcap"))).messages("/src/cloud")
    came = load(next(tmp_path.glob("runs/*-consumer/*.mcap"))).messages("/src/cloud")
    assert len(sent) == 12 and [m.payload for m in sent] == [m.payload for m in came]
    points = [codec.decode_payload(PointCloud, m.payload).points for m in sent]  # type: ignore[attr-defined]
    assert [hashlib.sha256(p.tobytes()).hexdigest() for p in points] == expected(12)
    recording = next(tmp_path.glob("runs/*-consumer/*.mcap"))
    replayed = subprocess.run(
        vgr("replay", str(recording)), env=env(), cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert replayed.returncode == 0, replayed.stdout + replayed.stderr  # bit-identical (exit 1 otherwise)
    assert "identical" in replayed.stdout and "/shift/cloud" in replayed.stdout


def test_a_full_pool_sends_bytes_meanwhile_and_every_cloud_arrives_whole_in_order(tmp_path):
    recipe = write_recipe(tmp_path, n=40, interval=0.0, delay=0.02)  # a burst into a slow consumer
    run_pair(recipe, "--no-record")
    rows = json.loads((tmp_path / "views.json").read_text())["rows"]
    assert [r["seq"] for r in rows] == list(range(1, 41)) and [r["sha"] for r in rows] == expected(40)
    views = [r["view"] for r in rows]
    assert views[0] and not all(views)  # views while the pool had room, the other route once it was full


# --------------------------------------------------------------------------- two hosts


@contextlib.contextmanager
def two_namespaces():
    """Two network namespaces joined by a veth pair with addresses in 127.0.0.0/8 (as
    tests/engine_core/test_security_netns.py makes them); yields (producer ns, consumer ns, producer address)."""
    tag = f"{os.getpid() % 100000}"
    a, b, a_if, b_if = f"vgrva{tag}", f"vgrvb{tag}", f"va{tag}", f"vb{tag}"
    addrs = {a: "127.78.0.1", b: "127.78.0.2"}

    def sh(*cmd: str) -> None:
        subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=30)

    try:
        made = subprocess.run(["ip", "netns", "add", a], capture_output=True, text=True, timeout=30)
        if made.returncode != 0:
            pytest.skip(f"cannot create a network namespace here: {made.stderr.strip()}")
        sh("ip", "netns", "add", b)
        sh("ip", "link", "add", a_if, "type", "veth", "peer", "name", b_if)
        for ns, link in ((a, a_if), (b, b_if)):
            sh("ip", "link", "set", link, "netns", ns)
            sh("ip", "netns", "exec", ns, "sysctl", "-qw", "net.ipv4.conf.all.route_localnet=1")
            sh("ip", "netns", "exec", ns, "sysctl", "-qw", f"net.ipv4.conf.{link}.route_localnet=1")
            sh("ip", "-n", ns, "addr", "add", f"{addrs[ns]}/30", "dev", link)
            sh("ip", "-n", ns, "link", "set", link, "up")
        yield a, b, addrs[a]
    finally:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None, reason="needs root and iproute2")
def test_across_two_hosts_the_same_recipe_sends_bytes_through_the_network(tmp_path):
    with two_namespaces() as (prod_ns, cons_ns, prod_addr):
        recipe = write_recipe(tmp_path, n=6, host=prod_addr)
        run_pair(recipe, "--no-record", prefix=(["ip", "netns", "exec", cons_ns], ["ip", "netns", "exec", prod_ns]))
    rows = json.loads((tmp_path / "views.json").read_text())["rows"]
    assert [r["seq"] for r in rows] == list(range(1, 7)) and [r["sha"] for r in rows] == expected(6)
    assert not any(r["view"] for r in rows)  # another host: no view of the sender's memory
    log = next(tmp_path.glob("runs/*-views-consumer/run.log")).read_text()
    assert "over a unix socket" not in log  # ... nor a link to it (engine.transport.local_link)


# --------------------------------------------------------------------------- killed mid-stream


def mapped_pools() -> int:
    return sum("memfd:vgr-views" in line for line in Path("/proc/self/maps").read_text().splitlines())


def child(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(HERE / "view_child.py"), *args], env=env(), stdout=subprocess.PIPE, text=True
    )


@contextlib.contextmanager
def bus_on_socket():
    folder = Path(tempfile.mkdtemp(prefix="vgr-v-"))  # short: a unix socket path has ~100 bytes
    endpoint = f"unixsock-stream/{folder / 'p.sock'}"
    bus = Bus(ZenohSettings(listen=[endpoint]))
    try:
        yield bus, endpoint
    finally:
        bus.close()
        shutil.rmtree(folder, ignore_errors=True)


def test_views_of_a_sender_killed_mid_stream_stay_whole_and_nothing_is_left(tmp_path):
    run = f"vk{os.getpid()}"
    with bus_on_socket() as (bus, endpoint):
        _, channel = bus.subscribe_remote(f"vgr/{run}/_wire/src/cloud")
        bus.host_peers(run, "b")  # this process maps this host's memory
        reader = ViewReader(0)
        sender = child("send", endpoint, run)
        held: list[tuple[int, np.ndarray]] = []
        deadline = time.monotonic() + 60
        killed = False
        while time.monotonic() < deadline:
            sample = channel.try_recv()
            if sample is None:
                if killed:
                    break
                time.sleep(0.001)
                continue
            att = sample.attachment.to_bytes()
            if att[4] == Kind.VIEW:
                seq = int.from_bytes(att[8:16], "little")
                view = np.frombuffer(reader.payload(sample.payload.to_bytes()), np.uint8)
                if len(held) < 15:
                    held.append((seq, view))  # kept across the kill
                elif not killed and seq >= 25:
                    sender.send_signal(signal.SIGKILL)  # mid-stream: it was writing the next one
                    sender.wait(30)
                    killed = True
                    time.sleep(0.2)  # what was on its way arrives
                assert view.tobytes() == payload(seq)
                del view  # (the held ones stay)
            del sample
        assert killed
        assert len(held) == 15 and all(v.tobytes() == payload(seq) for seq, v in held)  # still whole
        assert mapped_pools() == 2  # the dead sender's pool: mapped here, nowhere else
        held.clear()
        reader.close()
        gc.collect()
        assert mapped_pools() == 0  # the last mapping gone: the kernel frees the memfd, no file was left


def test_the_blocks_of_a_receiver_killed_while_holding_them_come_back(tmp_path):
    run = f"vr{os.getpid()}"
    with bus_on_socket() as (bus, endpoint):
        peers = bus.host_peers(run, "a")
        pool = ViewPool(peers, CONSUMERS)
        pub = bus.remote_publisher(f"vgr/{run}/_wire/src/cloud")
        holder = child("hold", endpoint, run, "5")
        try:
            deadline = time.monotonic() + 30
            while not (pub.matching_status.matching and peers.zids("b")) and time.monotonic() < deadline:
                time.sleep(0.01)
            sender = WireSender(pub, "src.cloud", bus.shm, pool)
            for k in range(1, 6):
                sender.send(payload(k), b"VGR\x01" + bytes(20) + b"Blob")
                time.sleep(0.005)
            assert holder.stdout is not None and holder.stdout.readline().strip() == "held 5"
            assert pool.shared == 5 and pool.in_flight() == 5  # it holds every one
            holder.send_signal(signal.SIGKILL)
            holder.wait(30)
            deadline = time.monotonic() + 30  # its session's end is seen within zenoh's lease at worst
            while pool.in_flight() and time.monotonic() < deadline:
                time.sleep(0.05)
            assert pool.in_flight() == 0  # nobody waited for any more
        finally:
            holder.kill()
            holder.wait(30)
