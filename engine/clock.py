"""Clocks of a run: wall time for real cells, simulated time for the simulated cell and replay.

Stages read time only through ``ctx.clock`` so that a simulated run and a replay never depend on
the wall clock (docs/design.md, determinism). Times are integer nanoseconds.

* :class:`WallClock`  ``time.time_ns()``; ``sleep`` really waits (interruptible by the run's stop).
* :class:`SimClock`   starts at a fixed epoch; ``sleep(dt)`` and ``advance_to(t)`` move it forward at
  once; it never goes backwards. Replay sets it to each recorded message's time.
"""

from __future__ import annotations

import threading
import time

NS = 1_000_000_000


class Clock:
    """Interface: ``now_ns()``, ``sleep(seconds, stop_event)``; ``simulated`` tells which kind."""

    simulated: bool = False

    def now_ns(self) -> int:
        raise NotImplementedError

    def now_s(self) -> float:
        return self.now_ns() / NS

    def sleep(self, seconds: float, stop: threading.Event | None = None) -> bool:
        """Sleep *seconds*; return False if *stop* was set before the time elapsed."""
        raise NotImplementedError


class WallClock(Clock):
    simulated = False

    def now_ns(self) -> int:
        return time.time_ns()

    def sleep(self, seconds: float, stop: threading.Event | None = None) -> bool:
        if seconds <= 0:
            return not (stop is not None and stop.is_set())
        if stop is None:
            time.sleep(seconds)
            return True
        return not stop.wait(seconds)


class SimClock(Clock):
    """Deterministic simulated time shared by the stages of one process."""

    simulated = True
    DEFAULT_EPOCH_NS = 1_700_000_000 * NS  # a fixed, recognisable epoch (2023-11-14)

    def __init__(self, start_ns: int = DEFAULT_EPOCH_NS) -> None:
        self._now = int(start_ns)
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        with self._lock:
            return self._now

    def advance_to(self, t_ns: int) -> int:
        """Move time forward to *t_ns* (never backwards); returns the new time."""
        with self._lock:
            self._now = max(self._now, int(t_ns))
            return self._now

    def advance(self, seconds: float) -> int:
        with self._lock:
            self._now += max(0, round(seconds * NS))
            return self._now

    def sleep(self, seconds: float, stop: threading.Event | None = None) -> bool:
        if stop is not None and stop.is_set():
            return False
        self.advance(seconds)
        return True


def make_clock(kind: str) -> Clock:
    if kind == "wall":
        return WallClock()
    if kind == "sim":
        return SimClock()
    raise ValueError(f"unknown clock {kind!r}: use 'wall' or 'sim'")
