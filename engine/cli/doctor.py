"""``vgr doctor``: checks the installation and the machine, and says what to fix.

Each check gives ``ok``, ``note`` (works, but know this) or ``problem`` (something vgr needs is
missing or wrong) with what was found and, for the last two, what to do:

* ``python``: the version vgr is made for (3.11);
* ``packages``: the installed version of each package vgr needs (numpy, scipy, open3d, small_gicp,
  kiss-icp, eclipse-zenoh, mcap, opencv, foxglove-sdk, cryptography, pydantic, pluggy) and of the
  device SDKs (pyrealsense2, ur-rtde, openvr: a note when absent, as only that device needs it);
* ``shared memory``: ``/dev/shm`` exists and holds a process's pool (engine/transport/shm.py) with
  room to spare (a container's default 64 MB holds two);
* ``private sockets``: the folder of the runs' unix sockets is this user's, mode 0700
  (engine/transport/endpoints.py);
* ``cpu``: the SIMD features (AVX2, AVX-512, FMA) by which the registration libraries may sum in
  another order: what to compare first when a recording made elsewhere replays ``different``;
* ``live view``: the default port of ``--view`` is free on 127.0.0.1;
* ``ros 2``: rclpy importable (a note either way: only the ROS 2 bridge needs it).

Exit code: 0 when nothing is a ``problem``, 1 otherwise (the exit-code table); ``--json`` prints
``{"format": "vgr.doctor/1", "ok", "outcome", "exit_code", "checks": [{"name", "status", "found",
"fix"}]}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import socket
import stat
import sys
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

from engine.exit_codes import ExitCode

DOCTOR_FORMAT = "vgr.doctor/1"
REQUIRED = ("numpy", "scipy", "open3d-cpu", "small_gicp", "kiss-icp", "eclipse-zenoh", "mcap")
REQUIRED += ("opencv-python-headless", "foxglove-sdk", "cryptography", "pydantic", "pluggy")
DEVICE_SDKS = {"pyrealsense2": "realsense_camera", "ur-rtde": "ur_robot", "openvr": "vive_tracker"}
SIMD_FLAGS = ("avx2", "avx512f", "fma")


@dataclass
class Check:
    name: str
    status: str  # ok | note | problem
    found: str
    fix: str = ""


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def check_python() -> Check:
    v = platform.python_version()
    if sys.version_info[:2] == (3, 11):
        return Check("python", "ok", v)
    return Check("python", "problem", v, "vgr is made for Python 3.11: make a 3.11 venv (`make install` does)")


def check_packages() -> list[Check]:
    found = {d: _version(d) for d in REQUIRED}
    missing = [d for d, v in found.items() if v is None]
    text = ", ".join(f"{d} {v}" for d, v in found.items() if v)
    out = [
        Check("packages", "problem" if missing else "ok", text, f"pip install {' '.join(missing)}" if missing else "")
    ]
    for dist, stage in DEVICE_SDKS.items():
        v = _version(dist)
        if v is None:
            out.append(Check(dist, "note", "not installed", f"only the {stage} stage needs it: pip install {dist}"))
        else:
            out.append(Check(dist, "ok", v))
    return out


def check_shared_memory(shm: Path = Path("/dev/shm")) -> Check:
    from engine.transport.shm import POOL_BYTES

    if not shm.is_dir():
        return Check("shared memory", "note", f"no {shm}", "large payloads between processes go as bytes (slower)")
    free = shutil.disk_usage(shm).free
    found = f"{shm}: {free / 2**20:.0f} MiB free, a process's pool is {POOL_BYTES / 2**20:.0f} MiB"
    if free < 2 * POOL_BYTES:
        fix = "give the container more shared memory (docker run --shm-size=512m) or free /dev/shm"
        return Check("shared memory", "note", found, fix)
    return Check("shared memory", "ok", found)


def check_private_sockets() -> Check:
    from engine.transport.endpoints import private_socket_dir

    try:
        folder = private_socket_dir()
    except PermissionError as exc:
        return Check(
            "private sockets", "problem", str(exc), "remove the folder or set XDG_RUNTIME_DIR to a private one"
        )
    mode = stat.S_IMODE(folder.stat().st_mode)
    return Check("private sockets", "ok", f"{folder} (mode {mode:o}, uid {os.getuid()})")


def check_cpu(cpuinfo: Path = Path("/proc/cpuinfo")) -> Check:
    try:
        flags = set(next(ln for ln in cpuinfo.read_text().splitlines() if ln.startswith("flags")).split(":")[1].split())
    except (OSError, StopIteration, IndexError):
        return Check("cpu", "note", f"{platform.machine()}: no {cpuinfo} to read", "")
    have = [f for f in SIMD_FLAGS if f in flags]
    found = f"{platform.machine()}, SIMD: {', '.join(have) or 'none of ' + ', '.join(SIMD_FLAGS)}"
    fix = (
        "the SIMD path can change the last bits of the registration libraries' sums: when `vgr replay` of a "
        "recording made on another machine says 'different', compare this line on both"
    )
    return Check("cpu", "note", found, fix)


def check_view_port(port: int | None = None) -> Check:
    from engine.recording.live_view import DEFAULT_PORT

    port = DEFAULT_PORT if port is None else port
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError as exc:
            return Check("live view", "note", f"port {port} is taken ({exc.strerror})", "use --view PORT")
    return Check("live view", "ok", f"port {port} free on 127.0.0.1")


def check_ros2() -> Check:
    v = _version("ros-rclpy") or _version("rclpy")
    if v is None:
        return Check("ros 2", "note", "rclpy not installed", "only the ROS 2 bridge needs it")
    return Check("ros 2", "ok", f"rclpy {v}")


def run_checks() -> list[Check]:
    return [
        check_python(),
        *check_packages(),
        check_shared_memory(),
        check_private_sockets(),
        check_cpu(),
        check_view_port(),
        check_ros2(),
    ]


def cmd_doctor(args: argparse.Namespace) -> int:
    checks = run_checks()
    code = ExitCode.NOT_OK if any(c.status == "problem" for c in checks) else ExitCode.OK
    if args.json:
        doc = {
            "format": DOCTOR_FORMAT,
            "ok": code == ExitCode.OK,
            "outcome": "ok" if code == ExitCode.OK else "problem",
        }
        print(json.dumps({**doc, "exit_code": int(code), "checks": [asdict(c) for c in checks]}))
        return code
    for c in checks:
        print(f"{c.status:8s} {c.name}: {c.found}" + (f"\n         -> {c.fix}" if c.fix else ""))
    return code


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("doctor", help="check the installation and the machine, and say what to fix")
    p.add_argument("--json", action="store_true", help="print the checks as JSON (format vgr.doctor/1)")
    p.set_defaults(func=cmd_doctor)
