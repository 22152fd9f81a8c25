"""The queue of one input port fed by a stage of the same process, with the idle fast path.

The producer's ``publish`` offers the message object itself (arrays frozen read-only, nothing
serialised — like ROS 2 intra-process communication), and END when its port ends. If the consumer
is idle (queue empty, nothing in flight, stage lock free) the producer's thread runs the consumer's
handler at once, saving a thread wake-up; otherwise the message waits in the queue for the port's
pump thread, which the stage starts when the first message has to wait (a port always handed over
inline never has one: engine.run.runtime.StageRuntime.start_threads). The queue is bounded: a
producer that outruns its consumer waits (backpressure), nothing is dropped. One port's messages
are handled in publication order, and the port never has two messages in flight.
(An input fed by another process has no queue of ours: see engine.run.remote_input.RemoteInput.)

Wake-ups are the expensive part of a hand-over (a thread switch and a GIL transfer each), so the
two sides wait on separate conditions of one lock and are notified only when someone waits for
exactly that: the pump when an item arrives, a producer when room appears. Marking a message done
(:meth:`release`) wakes nobody.
"""

from __future__ import annotations

import collections
import threading
from typing import Any


class _Marker:
    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    def __repr__(self) -> str:
        return f"<{self.name}>"


END = _Marker("end of stream")  # the producer's port ended (handled like a message, in order)
STOP = _Marker("stop")  # the run is stopping: the pump exits
Item = Any  # a Message, END or STOP


class PortInbox:
    def __init__(self, port: str, depth: int | None) -> None:
        self.port = port
        self.depth = depth  # None: unbounded
        self._items: collections.deque[Item] = collections.deque()
        self._lock = threading.Lock()
        self._not_empty = threading.Condition(self._lock)  # the pump waits here
        self._not_full = threading.Condition(self._lock)  # producers of a bounded inbox wait here
        self._inflight = False
        self._closed = False
        self._pump_waiting = False
        self._producers_waiting = 0
        self.high_water = 0

    # -- producer side -------------------------------------------------------------------------
    def claim_idle(self) -> bool:
        """If nothing is queued or in flight, mark one message in flight and return True."""
        with self._lock:
            if self._items or self._inflight or self._closed:
                return False
            self._inflight = True
            return True

    def put(self, item: Item, *, block: bool = True) -> bool:
        """Queue *item*; wait for room if bounded and *block*. False if the inbox is closed."""
        with self._lock:
            items = self._items
            if block and self.depth is not None:
                while len(items) >= self.depth and not self._closed:
                    self._producers_waiting += 1
                    try:
                        self._not_full.wait()
                    finally:
                        self._producers_waiting -= 1
            if self._closed and item is not STOP:
                return False
            items.append(item)
            if len(items) > self.high_water:
                self.high_water = len(items)
            if self._pump_waiting:
                self._not_empty.notify()
            return True

    # -- consumer side -------------------------------------------------------------------------
    def get(self) -> Item:
        """Next item (blocks); marks it in flight until :meth:`release`."""
        with self._lock:
            items = self._items
            while not items:
                self._pump_waiting = True
                try:
                    self._not_empty.wait()
                finally:
                    self._pump_waiting = False
            item = items.popleft()
            self._inflight = item is not STOP
            if self._producers_waiting:
                self._not_full.notify()
            return item

    def release(self) -> None:
        """The message taken by :meth:`get` or :meth:`claim_idle` is handled (nobody waits on this).

        No lock: only the thread that took the message clears the flag, as its last step, and a
        producer's :meth:`claim_idle` seeing it either still set (it queues) or cleared (it
        handles inline) is correct either way."""
        self._inflight = False

    def close(self) -> None:
        """No more messages: wake the pump (it exits) and any producer waiting for room."""
        with self._lock:
            self._closed = True
            self._items.append(STOP)
            self._not_empty.notify_all()
            self._not_full.notify_all()

    def __len__(self) -> int:
        return len(self._items)
