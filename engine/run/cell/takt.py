"""Cycle-time figures of a cell service: per part of a cycle (``total``, and each service the job
called, e.g. ``camera.capture``, ``matcher.match_first``), p50 / p99 / max over the last cycles.

A bounded window (``WINDOW`` cycles) so a service that runs for months keeps constant memory and its
figures say how it runs now, not how it ran last month; ``count`` is the total since the start.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np

WINDOW = 1000


class TaktTimes:
    """Durations (ms) of the last WINDOW cycles, by part."""

    def __init__(self, window: int = WINDOW) -> None:
        self._window = window
        self._parts: dict[str, deque[float]] = {}
        self._lock = threading.Lock()
        self.count = 0

    def add(self, durations_ms: dict[str, float]) -> None:
        """One cycle's durations (``total`` and its parts)."""
        with self._lock:
            self.count += 1
            for part, ms in durations_ms.items():
                self._parts.setdefault(part, deque(maxlen=self._window)).append(float(ms))

    def figures(self) -> dict[str, dict[str, float]]:
        """part -> {p50, p99, max, n} over the window (empty before the first cycle)."""
        with self._lock:
            snapshot = {part: np.array(values) for part, values in self._parts.items() if values}
        return {
            part: {
                "p50": float(np.percentile(v, 50)),
                "p99": float(np.percentile(v, 99)),
                "max": float(v.max()),
                "n": int(v.size),
            }
            for part, v in snapshot.items()
        }
