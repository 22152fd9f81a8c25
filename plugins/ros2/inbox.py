"""What a bridge stage keeps of a subscribed topic: the latest serialized message, counted, and a
wait for one that arrives after a given moment.

The executor thread's callback (:meth:`Inbox.put`) only stores bytes and wakes waiters; decoding
happens on the stage's thread when the message is used, so a 30 Hz camera costs nothing between
captures and a malformed message fails the capture that takes it, naming the topic, and nothing else.
Time here is the host's monotonic clock (when a message arrived), not the run's clock: a
capture waits for real data in a real cell.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass


@dataclass(frozen=True)
class Received:
    """One message as it arrived: its serialized bytes, its number on the topic, when it came."""

    data: bytes
    number: int
    arrived_s: float  # time.monotonic()


class NoMessageError(TimeoutError):
    """No (new) message came on the topic in time."""


class Inbox:
    """The latest message of one topic and how many came."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self._cond = threading.Condition()
        self._latest: Received | None = None
        self.count = 0

    def put(self, data: bytes) -> None:
        """Called on the executor thread with each message's bytes."""
        with self._cond:
            self.count += 1
            self._latest = Received(bytes(data), self.count, time.monotonic())
            self._cond.notify_all()

    def latest(self) -> Received | None:
        with self._cond:
            return self._latest

    def next_after(self, number: int, timeout_s: float, *, skip: int = 0) -> Received:
        """The first message numbered above *number* + *skip* (waits up to *timeout_s*)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._latest is None or self._latest.number <= number + skip:
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = "none yet" if self._latest is None else f"the last was number {self._latest.number}"
                    raise NoMessageError(
                        f"no new message on ROS 2 topic {self.topic!r} within {timeout_s:g} s "
                        f"({self.count} received in all, {seen}): is the publisher running, on this domain, "
                        "with a compatible QoS?"
                    )
                self._cond.wait(left)
            return self._latest

    def fresh(self, timeout_s: float, *, skip: int = 0) -> Received:
        """The first message that arrives from now on (after *skip* more)."""
        with self._cond:
            now = self.count
        return self.next_after(now, timeout_s, skip=skip)
