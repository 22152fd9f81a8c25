"""A secured run across two network namespaces the test makes itself (a veth pair with addresses in
127.0.0.0/8): it docks as it does in one process, and cutting the link moves nothing.

Needs root and iproute2 (``ip netns``); skipped otherwise. Each namespace and link is named after
the test's process id and removed at the end.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from process_helpers import ROOT, env, run_vgr, vgr

from engine.messages import codec
from engine.recording.reader import load

pytestmark = [
    pytest.mark.subprocess,
    pytest.mark.timeout(300),
    pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None, reason="needs root and iproute2"),
]

CELL, VISION = "127.77.0.1", "127.77.0.2"
PORT = 7447


def sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=30)


@contextlib.contextmanager
def two_namespaces() -> Iterator[tuple[str, str, str]]:
    """Namespaces (cell, vision) joined by a veth pair; yields their names and the cell's link."""
    tag = f"{os.getpid() % 100000}"
    cell_ns, vision_ns = f"vgrc{tag}", f"vgrv{tag}"
    cell_if, vision_if = f"vc{tag}", f"vv{tag}"
    try:
        made = subprocess.run(["ip", "netns", "add", cell_ns], capture_output=True, text=True, timeout=30)
        if made.returncode != 0:  # a container without CAP_SYS_ADMIN
            pytest.skip(f"cannot create a network namespace here: {made.stderr.strip()}")
        sh("ip", "netns", "add", vision_ns)
        sh("ip", "link", "add", cell_if, "type", "veth", "peer", "name", vision_if)
        for ns, link, addr in ((cell_ns, cell_if, CELL), (vision_ns, vision_if, VISION)):
            sh("ip", "link", "set", link, "netns", ns)
            # 127.0.0.0/8 off the loopback interface: allowed per interface; lo stays down so the
            # other end's address is not taken for a local one
            sh("ip", "netns", "exec", ns, "sysctl", "-qw", "net.ipv4.conf.all.route_localnet=1")
            sh("ip", "netns", "exec", ns, "sysctl", "-qw", f"net.ipv4.conf.{link}.route_localnet=1")
            sh("ip", "-n", ns, "addr", "add", f"{addr}/30", "dev", link)
            sh("ip", "-n", ns, "link", "set", link, "up")
        yield cell_ns, vision_ns, cell_if
    finally:
        for ns in (cell_ns, vision_ns):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


def split_dock(tmp_path: Path) -> Path:
    """The eye-in-hand dock with the robot and camera in process `cell` and the rest in `vision`,
    secured, over TLS between the two namespaces' addresses."""
    data = yaml.safe_load((ROOT / "recipes/eye_in_hand_dock.yaml").read_text())
    for name, stage in data["stages"].items():
        stage["process"] = "cell" if name in ("robot", "camera") else "vision"
    data["stages"]["matcher"]["params"]["template"] = str(ROOT / "recipes/templates/eye_in_hand.vgrtpl")
    data["security"] = {"certs": "certs"}
    data["processes"] = {
        "cell": {"listen": [f"tls/{CELL}:{PORT}"], "connect": []},
        "vision": {"listen": [], "connect": [f"tls/{CELL}:{PORT}"]},
    }
    recipe = tmp_path / "dock.yaml"
    recipe.write_text(yaml.safe_dump(data, sort_keys=False))
    made = subprocess.run(
        vgr("certs", "make", str(recipe), "--out", str(tmp_path / "certs")), env=env(), capture_output=True, text=True
    )
    assert made.returncode == 0, made.stdout + made.stderr
    return recipe


def run_in(ns: str, recipe: Path, process: str, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        ["ip", "netns", "exec", ns, *vgr("run", str(recipe), "--process", process, "--no-progress", *extra)],
        env=env(),
        cwd=recipe.parent,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def docking_error(out: str) -> str:
    m = re.search(r"docking error ([\d.]+ mm / [\d.]+ deg)", out)
    assert m, out
    return m.group(1)


def test_a_secured_dock_across_two_namespaces_docks_as_in_one_process(tmp_path):
    one = run_vgr("run", str(ROOT / "recipes/eye_in_hand_dock.yaml"), "--no-progress", cwd=tmp_path)
    assert one.returncode == 0, one.stdout + one.stderr
    recipe = split_dock(tmp_path)
    with two_namespaces() as (cell_ns, vision_ns, _):
        cell = run_in(cell_ns, recipe, "cell")
        vision = run_in(vision_ns, recipe, "vision")
        out_v, _ = vision.communicate(timeout=150)
        out_c, _ = cell.communicate(timeout=60)
    assert vision.returncode == 0, out_v
    assert cell.returncode == 0, out_c
    assert docking_error(out_v) == docking_error(one.stdout)


def _tcp_established(ns: str, port: int) -> bool:
    table = subprocess.run(["ip", "netns", "exec", ns, "cat", "/proc/net/tcp"], capture_output=True, text=True).stdout
    return any(f.split()[3] == "01" and f.split()[1].endswith(f":{port:04X}") for f in table.splitlines()[1:])


def _robot_poses(run_dir: Path) -> list[np.ndarray]:
    rec = load(next(run_dir.glob("runs/*-cell/*.mcap")))
    return [codec.decode_payload(codec.registry.get(m.type_name), m.payload).T for m in rec.messages("/robot/tcp_pose")]


def test_cutting_the_link_for_15_s_raises_the_alarm_and_moves_nothing(tmp_path):
    recipe = split_dock(tmp_path)
    photo = np.array(yaml.safe_load(recipe.read_text())["vars"]["photo_pose"]["matrix"])
    with two_namespaces() as (cell_ns, vision_ns, cell_if):
        cell = run_in(cell_ns, recipe, "cell")
        vision = run_in(vision_ns, recipe, "vision", "-p", "guidance.timeout_s=20")
        deadline = time.monotonic() + 60
        while not _tcp_established(cell_ns, PORT) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)  # the start barrier: the guidance's first calls are under way
        sh("ip", "-n", cell_ns, "link", "set", cell_if, "down")
        time.sleep(15.0)
        sh("ip", "-n", cell_ns, "link", "set", cell_if, "up")
        out_v, _ = vision.communicate(timeout=120)
        out_c, _ = cell.communicate(timeout=120)
    # each side names the other as lost (its zenoh lease ran out during the cut) and fails
    assert vision.returncode == 4 and "peer_lost" in out_v and "'cell'" in out_v, out_v
    assert cell.returncode == 4 and "peer_lost" in out_c and "'vision'" in out_c, out_c
    assert "docking error" not in out_v  # no docking happened
    poses = _robot_poses(tmp_path)
    assert poses
    final = poses[-1]
    # the robot is where it started or at the photo pose it was sent to before the cut: no correction
    assert np.allclose(final, poses[0], atol=1e-6) or np.allclose(final[:3, 3], photo[:3, 3], atol=1e-4), final
