"""Helpers of the model-gap stage tests (camera_gap, depth_gap): a stage context that keeps what the
stage publishes and the events it raises, with no bus and no run."""

from __future__ import annotations

import logging

from engine.clock import WallClock
from engine.stage import StageContext


class RecordingContext(StageContext):
    """A stage context that keeps what the stage publishes and its events (no bus, no run)."""

    def __init__(self, tmp_path, name: str) -> None:
        super().__init__(name, "test", 3, WallClock(), logging.getLogger("test"), None)
        self.run_dir = tmp_path
        self.published: list[tuple[str, object]] = []
        self.events: list[tuple[str, str, str]] = []

    def publish(self, port, msg) -> None:
        self.published.append((port, msg))

    def event(self, level, code, message, **details) -> None:
        self.events.append((level, code, message))

    def assert_failed(self, reason_part: str) -> None:
        """The stage published one ``failed`` result whose reason says *reason_part*, with a
        ``<stage>_failed`` warning."""
        ((_, msg),) = self.published
        assert msg.verdict == "failed" and reason_part in msg.reasons[0]
        assert any(code == f"{self.name}_failed" for _, code, _ in self.events)
