"""kill -9 in the middle of a recorded run: every chunk flushed before the kill is read back."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from engine.cli import main
from engine.recording import RecordingError, load

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]
ROOT = Path(__file__).resolve().parents[2]
FLUSH_S = 0.5

RECIPE = f"""
name: endless
clock: wall
record: {{flush_interval_s: {FLUSH_S}}}
stages:
  source: {{type: synthetic_cloud, params: {{n_points: 300, frames: 1000000, rate_hz: 100}}}}
  move: {{type: transform_cloud, inputs: {{cloud: source.cloud}}, params: {{translation_m: [0, 0, 1]}}}}
  stats: {{type: cloud_stats, inputs: {{cloud: move.cloud}}}}
"""


def test_kill_9_keeps_flushed_chunks_and_recover_restores_them(tmp_path, capsys):
    recipe = tmp_path / "endless.yaml"
    recipe.write_text(RECIPE)
    rec_path = tmp_path / "crash.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine.cli", "run", str(recipe), "--no-progress", "--record", str(rec_path)],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    deadline = time.monotonic() + 60
    while (not rec_path.exists() or rec_path.stat().st_size < 200_000) and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(1.0)
    os.kill(proc.pid, signal.SIGKILL)
    killed_at = time.time_ns()
    proc.wait(10)
    with pytest.raises(RecordingError, match="vgr recover"):
        load(rec_path)
    out = tmp_path / "recovered.mcap"
    assert main(["recover", str(rec_path), "-o", str(out)]) == 0
    assert "truncated" in capsys.readouterr().out
    rec = load(out)  # an ordinary, indexed recording again
    seqs = [m.seq for m in rec.messages("/source/cloud")]
    assert len(seqs) > 50 and seqs == list(range(1, len(seqs) + 1))  # nothing flushed is missing, no gap
    moved = [m.seq for m in rec.messages("/move/cloud")]
    assert moved == list(range(1, len(moved) + 1)) and len(moved) >= len(seqs) - 10
    assert rec.recipe_text == RECIPE and rec.metadata["vgr.run"]["recipe"] == "endless"
    lost_s = (killed_at - max(m.log_time for m in rec.messages())) / 1e9
    assert lost_s < FLUSH_S + 2.0, f"{lost_s:.2f} s of data lost with a {FLUSH_S} s flush interval"
