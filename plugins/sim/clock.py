"""Simulated time: a clock that only moves when the simulation advances it (never the wall clock).

Time is kept in integer nanoseconds (docs/design.md timestamps) and read in seconds by the sim models.
Anything that needs "now" takes a callable returning seconds, so a :class:`SimClock`'s
:meth:`~SimClock.now_s`, a replay clock or a test lambda all fit.
"""

from __future__ import annotations

NS_PER_S = 1_000_000_000


class SimClock:
    """A monotonic simulated clock in integer nanoseconds."""

    def __init__(self, start_ns: int = 0) -> None:
        if start_ns < 0:
            raise ValueError("start time must be >= 0")
        self._ns = int(start_ns)

    def now_ns(self) -> int:
        return self._ns

    def now_s(self) -> float:
        return self._ns / NS_PER_S

    def __call__(self) -> float:
        return self.now_s()

    def advance(self, dt_s: float) -> float:
        """Move time forward by ``dt_s`` seconds (>= 0); returns the new time in seconds."""
        if not dt_s >= 0:
            raise ValueError(f"simulated time only moves forward; got dt = {dt_s} s")
        self._ns += round(dt_s * NS_PER_S)
        return self.now_s()

    def advance_to(self, t_s: float) -> float:
        """Move time forward to ``t_s`` (no-op if already there; error if it is in the past)."""
        target = round(t_s * NS_PER_S)
        if target < self._ns:
            raise ValueError(f"cannot move the clock back from {self.now_s()} s to {t_s} s")
        self._ns = target
        return self.now_s()
