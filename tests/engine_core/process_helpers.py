"""Running `vgr` in child processes for the tests of runs spread over processes (and intruders), and of
the tools that watch a live run from outside (topics, play, the layout, the live view)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "recipes" / "demo.yaml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def vgr(*args: str) -> list[str]:
    return [sys.executable, "-m", "engine.cli.main", *args]


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


def demo_streaming(rate_hz: float, frames: int, points: int) -> list[str]:
    """``vgr run`` arguments of the demo recipe publishing *frames* clouds at *rate_hz* on the wall clock."""
    overrides = ["clock=wall", f"source.rate_hz={rate_hz:g}", f"source.frames={frames}", f"vars.n_points={points}"]
    return ["run", str(DEMO), "--no-progress", *(a for o in overrides for a in ("-p", o))]


def run_vgr(*args: str, cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """`vgr ARGS` in a child, waited for, output captured."""
    return subprocess.run(vgr(*args), env=env(), cwd=cwd, capture_output=True, text=True, timeout=timeout)
