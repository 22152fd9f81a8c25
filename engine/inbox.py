"""The queue of one input port of one stage, with the idle fast path.

Messages reach a port in two ways:

* from a producer stage in the **same process**: the producer's ``publish`` offers the message
  object itself (arrays frozen read-only, nothing serialised — like ROS 2 intra-process
  communication). If the consumer is idle (queue empty, nothing in flight, stage lock free) the
  producer's thread runs the consumer's handler at once, saving a thread wake-up; otherwise the
  message waits in the queue for the port's pump thread. The queue is bounded: a producer that
  outruns its consumer waits (backpressure), nothing is dropped.
* from a producer in **another process**: zenoh's receive thread appends the raw sample (never
  blocking: that thread also carries service replies); the pump thread decodes it.

Either way one port's messages are handled in publication order, and the port never has two
messages in flight.
"""

from __future__ import annotations

import collections
import threading
from typing import Any

LOCAL, REMOTE, STOP = 0, 1, 2
Item = tuple[int, Any, Any]


class PortInbox:
    def __init__(self, port: str, depth: int | None) -> None:
        self.port = port
        self.depth = depth  # None: unbounded (remote inputs)
        self._items: collections.deque[Item] = collections.deque()
        self._cv = threading.Condition(threading.Lock())
        self._inflight = False
        self._closed = False
        self._waiting = 0  # threads blocked on the condition (notify only when someone waits)
        self.high_water = 0

    # -- producer side -------------------------------------------------------------------------
    def claim_idle(self) -> bool:
        """If nothing is queued or in flight, mark one message in flight and return True."""
        with self._cv:
            if self._items or self._inflight or self._closed:
                return False
            self._inflight = True
            return True

    def put(self, item: Item, *, block: bool = True) -> bool:
        """Queue *item*; wait for room if bounded and *block*. False if the inbox is closed."""
        with self._cv:
            while block and self.depth is not None and len(self._items) >= self.depth and not self._closed:
                self._wait()
            if self._closed and item[0] != STOP:
                return False
            self._items.append(item)
            self.high_water = max(self.high_water, len(self._items))
            if self._waiting:
                self._cv.notify_all()
            return True

    def __call__(self, sample: Any) -> None:
        """zenoh callback for samples from other processes (must never block)."""
        self.put((REMOTE, sample, None), block=False)

    # -- consumer side -------------------------------------------------------------------------
    def get(self) -> Item:
        """Next item (blocks); marks it in flight until :meth:`release`."""
        with self._cv:
            while not self._items:
                self._wait()
            item = self._items.popleft()
            self._inflight = item[0] != STOP
            if self._waiting:
                self._cv.notify_all()
            return item

    def release(self) -> None:
        with self._cv:
            self._inflight = False
            if self._waiting:
                self._cv.notify_all()

    def _wait(self) -> None:
        self._waiting += 1
        try:
            self._cv.wait()
        finally:
            self._waiting -= 1

    def close(self) -> None:
        """No more messages: wake the pump (it exits) and any producer waiting for room."""
        with self._cv:
            self._closed = True
            self._items.append((STOP, None, None))
            self._cv.notify_all()

    def __len__(self) -> int:
        return len(self._items)
