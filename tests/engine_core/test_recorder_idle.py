"""The recorder's writer thread sleeps while there is nothing to write: a cell service waits between
cycles for minutes, and a writer that polled with a zero timeout once its flush was due spun a whole
core (found by benchmarks/cell_service.py: 1.0 core per idle service)."""

from __future__ import annotations

import queue
import threading
import time

from engine.recipe.model import RecordSettings
from engine.recording.recorder import Recorder


class CountingQueue(queue.SimpleQueue):  # type: ignore[type-arg]
    gets = 0

    def get(self, block: bool = True, timeout: float | None = None):  # type: ignore[no-untyped-def]
        CountingQueue.gets += 1
        return super().get(block, timeout)


class Writer:
    flushes = 0

    def flush(self) -> None:
        Writer.flushes += 1


def test_an_idle_writer_waits_instead_of_polling():
    rec = Recorder.__new__(Recorder)
    rec.settings = RecordSettings(flush_interval_s=0.01)
    rec.error, rec.path = None, "idle.mcap"
    rec._q = CountingQueue()
    rec._writer = Writer()
    rec._write = lambda item: None  # type: ignore[method-assign]
    rec._close = lambda summary: None  # type: ignore[method-assign]
    thread = threading.Thread(target=rec._write_loop, daemon=True)
    thread.start()
    rec._q.put(("msg",))  # one item: flushed within the interval, then nothing more to do
    time.sleep(0.3)  # (30 flush intervals of idleness; not a timing assertion)
    idle_gets = CountingQueue.gets
    rec._q.put(("end", None))
    thread.join(5.0)
    assert not thread.is_alive()
    assert Writer.flushes == 1
    assert idle_gets <= 4, f"the idle writer polled its queue {idle_gets} times"
