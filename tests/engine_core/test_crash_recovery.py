"""kill -9 in the middle of a recorded run: every chunk flushed before the kill is read back, and the
data lost is at most about one flush interval.

The recipe's ``chunk_size`` is far larger than what the run writes, so no chunk ever closes because
it is full: only the recorder's timed flush (``record.flush_interval_s``, default 1 s) puts data in
the file. With timed flushing broken, nothing but the header would survive; with a flush interval
longer than configured, the kill below loses more than the bound.

When to kill: the file grows only when the recorder flushes, so the test watches its size and
kills ``interval + KILL_AFTER_S`` after it saw a flush land. A recorder that flushes on time has
flushed again since (about ``interval`` after the one seen), so about ``KILL_AFTER_S`` of data is
lost, well inside the bound ``interval + MARGIN_S``; one that has not flushed again by then loses
more than ``interval + KILL_AFTER_S`` > bound, and fails every time. What may legitimately delay a
flush on a loaded 2-core machine — the writer thread waiting for a CPU or the GIL, compressing its
chunk — or delay this test noticing one, is tens of ms; the test still passes with a flush up to
``KILL_AFTER_S`` late or noticed up to ``interval - KILL_AFTER_S + MARGIN_S`` (>= 0.4 s) late. The
data rate is low (100-point clouds at 50 Hz) so the writer never runs behind its queue.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from engine.cli.main import main
from engine.recipe.model import RecordSettings
from engine.recording.reader import RecordingError, load

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(180)]
ROOT = Path(__file__).resolve().parents[2]
CHUNK_SIZE = 256 << 20  # never reached: only the timed flush writes chunks
MARGIN_S = 0.3  # data lost may exceed the flush interval by this much
KILL_AFTER_S = 0.4  # the kill comes interval + this after a flush is seen (> MARGIN_S: see above)
DEFAULT_FLUSH_S = RecordSettings().flush_interval_s


def recipe_text(flush_s: float | None) -> str:
    flush = f", flush_interval_s: {flush_s}" if flush_s is not None else ""
    return f"""
name: endless
clock: wall
record: {{chunk_size: {CHUNK_SIZE}{flush}}}
stages:
  source: {{type: synthetic_cloud, params: {{n_points: 100, frames: 1000000, rate_hz: 50}}}}
  move: {{type: transform_cloud, inputs: {{cloud: source.cloud}}, params: {{translation_m: [0, 0, 1]}}}}
  stats: {{type: cloud_stats, inputs: {{cloud: move.cloud}}}}
"""


def wait_for_growth(path: Path, size: int, deadline: float) -> int:
    """Poll until *path* is larger than *size*; return the new size."""
    while time.monotonic() < deadline:
        new = path.stat().st_size if path.exists() else 0
        if new > size:
            return new
        time.sleep(0.01)
    raise AssertionError(f"{path.name} did not grow past {size} bytes: is the recorder flushing?")


@pytest.mark.parametrize("flush_s", [0.5, None], ids=["flush_0.5s", "flush_default"])
def test_kill_9_keeps_flushed_chunks_and_recover_restores_them(tmp_path, capsys, flush_s):
    interval = flush_s if flush_s is not None else DEFAULT_FLUSH_S
    assert interval == 1.0 or flush_s is not None, "the documented default is 1 s"
    text = recipe_text(flush_s)
    recipe = tmp_path / "endless.yaml"
    recipe.write_text(text)
    rec_path = tmp_path / "crash.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine.cli.main", "run", str(recipe), "--no-progress", "--record", str(rec_path)],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        deadline = time.monotonic() + 90
        size = 0
        for _ in range(4):  # start-up, then a few flushes of data
            size = wait_for_growth(rec_path, size, deadline)
        size = wait_for_growth(rec_path, size, deadline)
        seen_flush = time.monotonic()
        time.sleep(max(0.0, seen_flush + interval + KILL_AFTER_S - time.monotonic()))
    finally:
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
    assert rec.recipe_text == text and rec.metadata["vgr.run"]["recipe"] == "endless"
    lost_s = (killed_at - max(m.log_time for m in rec.messages())) / 1e9
    assert lost_s <= interval + MARGIN_S, (
        f"{lost_s:.2f} s of data lost with a {interval:g} s flush interval (bound {interval + MARGIN_S:g} s)"
    )


def test_recover_never_writes_over_its_input_or_an_existing_file(tmp_path, capsys):
    src = tmp_path / "run.mcap"
    assert main(["run", "recipes/demo.yaml", "-p", "source.frames=3", "--no-progress", "--record", str(src)]) == 0
    before = src.read_bytes()
    capsys.readouterr()
    for argv in (["-o", str(src)], ["-o", str(tmp_path / "." / "run.mcap")]):
        assert main(["recover", str(src), *argv]) == 2
        assert "is the recording being recovered" in capsys.readouterr().err
    other = tmp_path / "other.mcap"
    other.write_bytes(b"keep me")
    assert main(["recover", str(src), "-o", str(other)]) == 2
    assert "exists" in capsys.readouterr().err and other.read_bytes() == b"keep me"
    assert main(["recover", str(src), "-o", str(other), "--force"]) == 0
    assert load(other).records and src.read_bytes() == before
    assert not list(tmp_path.glob(".*partial"))  # no temporary file left behind
