"""Replay regression: every golden recording in recordings/ replays bit for bit.

Each re-run stage's outputs and every service request must be *identical* to the recorded bytes;
"within tolerance" is a failure here, as is "different" (replay's promise is bit for bit, and a
stage whose outputs drift by an ulp from run to run is a determinism bug to find, not to tolerate).
A failure here means a stage's output changed. If the change is intended, refresh the golden
files with `make golden` (or `vgr replay FILE --update`) and commit them with the change.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.recording.diff import IDENTICAL
from engine.recording.replay import replay

RECORDINGS = sorted((Path(__file__).resolve().parents[2] / "recordings").glob("*.mcap"))


def test_there_are_golden_recordings_and_they_are_small():
    assert RECORDINGS, "recordings/ has no golden recordings"
    assert sum(p.stat().st_size for p in RECORDINGS) < 8_000_000


@pytest.mark.parametrize("path", RECORDINGS, ids=[p.stem for p in RECORDINGS])
def test_golden_recording_replays_identical(path):
    report, _, _ = replay(path)
    assert report.rerun, "nothing was re-run"
    verdicts = [*report.streams, *report.requests]
    assert verdicts, "the replay compared nothing"
    bad = [
        f"{v.topic}: {v.verdict}: {v.first_difference or f'max |diff| {v.max_abs_diff:.3g}'}"
        for v in verdicts
        if v.verdict != IDENTICAL
    ]
    assert not bad and not report.failures, "\n".join(bad + report.failures)
