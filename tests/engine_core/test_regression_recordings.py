"""Replay regression: every golden recording in recordings/ replays without a difference.

A failure here means a stage's output changed. If the change is intended, refresh the golden
files with `make golden` (or `vgr replay FILE --update`) and commit them with the change.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.diff import DIFFERENT
from engine.replay import replay

RECORDINGS = sorted((Path(__file__).resolve().parents[2] / "recordings").glob("*.mcap"))


def test_there_are_golden_recordings_and_they_are_small():
    assert RECORDINGS, "recordings/ has no golden recordings"
    assert sum(p.stat().st_size for p in RECORDINGS) < 8_000_000


@pytest.mark.parametrize("path", RECORDINGS, ids=[p.stem for p in RECORDINGS])
def test_golden_recording_replays_without_difference(path):
    report, _, _ = replay(path)
    assert report.rerun, "nothing was re-run"
    bad = [f"{v.topic}: {v.first_difference}" for v in (*report.streams, *report.requests) if v.verdict == DIFFERENT]
    assert not bad and not report.failures, "\n".join(bad + report.failures)
