"""What one process's run comes to: its :class:`RunSummary` (per-stage counters, events, how it
ended), the outcome named for a cell controller and the exit code of ``vgr run`` for it, or the
:class:`RunError` that it could not start.

The runner (engine.run.runner) makes the summary; its membership of a multi-process run
(engine.run.membership) raises RunError when the run's processes do not come together. Both import it
from here, so neither needs the other's module (tests/engine_core/test_import_graph.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from engine.exit_codes import OUTCOME_EXIT_CODES
from engine.messages import Event
from engine.run.runtime import StageStats


class RunError(RuntimeError):
    """The run could not start (bus, stage construction, start-up barrier)."""


@dataclass
class RunSummary:
    run_id: str
    recipe: str
    process: str
    ok: bool
    stop_reason: str | None
    stages: list[StageStats]
    wall_s: float
    events: list[Event] = field(default_factory=list)  # warnings, errors and alarms
    artifacts: dict[str, str] = field(default_factory=dict)  # e.g. recording path
    stop_to_end_s: float | None = None  # a stopped run: from the stop to the end of its last stage's threads
    # large payloads this process sent to other processes through shared memory, and those sent as
    # bytes because the pool was full or the host has none (engine.transport.shm); empty with shared memory off
    shared_memory: dict[str, int] = field(default_factory=dict)

    @property
    def outcome(self) -> str:
        """What the job came to, for a cell controller: ``ok``; ``refused`` (the run went through but
        a stage raised an alarm: a dock, move or calibration step was refused, so its motion was not
        done); ``failed`` (a stage failed); ``interrupted`` (Ctrl-C or a stop request)."""
        if self.stop_reason and "interrupted" in self.stop_reason:
            return "interrupted"
        if not self.ok:
            return "failed"
        if any(e.level == "alarm" for e in self.events):
            return "refused"
        return "ok"

    @property
    def exit_code(self) -> int:
        """The exit code of ``vgr run`` for :attr:`outcome` (engine.exit_codes)."""
        return OUTCOME_EXIT_CODES[self.outcome]
