"""Running `vgr` in child processes for the tests of runs spread over processes (and intruders)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def vgr(*args: str) -> list[str]:
    return [sys.executable, "-m", "engine.cli", *args]


def env() -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join([str(ROOT / "tests"), str(ROOT), e.get("PYTHONPATH", "")])
    return e


def start(recipe: Path, process: str, cwd: Path, *extra: str) -> subprocess.Popen[str]:
    """`vgr run RECIPE --process PROCESS` in a child, output captured."""
    return subprocess.Popen(
        vgr("run", str(recipe), "--process", process, "--no-progress", *extra),
        env=env(),
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
