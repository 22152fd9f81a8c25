"""Ctrl-C (or SIGTERM) while a process waits at the start-up barrier for the others of its run: the
stop is what happened, exit 130 (interrupted), not 2 (a run that could not start)."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from process_helpers import start

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]

TWO_PROCESSES = """
vgr: 1
name: barrier
run_id: barrier_{tag}
processes: {{a: {{listen: [private]}}, b: {{listen: [private]}}}}
stages:
  source: {{type: synthetic_cloud, process: a, params: {{n_points: 50, frames: 2}}}}
  stats: {{type: cloud_stats, process: b, inputs: {{cloud: source.cloud}}}}
"""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_at_the_start_barrier_exits_130(tmp_path: Path, signum: int) -> None:
    recipe = tmp_path / "barrier.yaml"
    recipe.write_text(TWO_PROCESSES.format(tag=f"{signum}_{int(time.time() * 1000) % 10**8}"))
    p = start(recipe, "a", tmp_path, "--ready-timeout", "60", "--runs-dir", str(tmp_path))
    try:
        time.sleep(4.0)  # (process b never comes: a waits at its barrier)
        assert p.poll() is None, p.communicate()[0]
        p.send_signal(signum)
        out, _ = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, out
    assert "Traceback" not in out and "interrupted" in out, out
