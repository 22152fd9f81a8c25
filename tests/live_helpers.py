"""Helpers of the tests that watch a live run from outside (topics, play, the layout, the live view):
a free loopback port, the ``vgr`` command line, and the demo recipe streaming on the wall clock."""

from __future__ import annotations

import os
import socket
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recipes" / "demo.yaml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def vgr(*args: str) -> list[str]:
    """The argv of ``vgr ARGS`` run from this checkout."""
    return [sys.executable, "-m", "engine.cli", *args]


def vgr_env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def demo_streaming(rate_hz: float, frames: int, points: int) -> list[str]:
    """``vgr run`` arguments of the demo recipe publishing *frames* clouds at *rate_hz* on the wall clock."""
    overrides = ["clock=wall", f"source.rate_hz={rate_hz:g}", f"source.frames={frames}", f"vars.n_points={points}"]
    return ["run", str(DEMO), "--no-progress", *(a for o in overrides for a in ("-p", o))]
