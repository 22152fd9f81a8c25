"""A minimal StageContext for unit tests of adapter stages (no bus): keeps what the stage publishes.

Runs on a simulated clock; ``sleep`` advances it. Integration through the real engine (Runner,
zenoh, typed ports) is tested separately in test_adapters_in_a_run.py.
"""

from __future__ import annotations

import logging
import threading
from collections import defaultdict
from typing import Any

from engine.clock import SimClock
from engine.messages import Event, Message, freeze
from engine.stage import Stage, StageContext, stage_rng


class CollectingContext(StageContext):
    def __init__(self, name: str = "dev", seed: int = 0) -> None:
        self.name = name
        self.run_id = "unit"
        self.seed = seed
        self.rng = stage_rng(seed, name)
        self.clock = SimClock()
        self.log = logging.getLogger(f"test.{name}")
        self.published: dict[str, list[Message]] = defaultdict(list)
        self.events: list[Event] = []
        self.stop_event = threading.Event()
        self._seq: dict[str, int] = defaultdict(int)

    def publish(self, port: str, msg: Message) -> None:
        self._seq[port] += 1
        msg.seq = self._seq[port]
        if not msg.stamp_ns:
            msg.stamp_ns = self.clock.now_ns()
        self.published[port].append(freeze(msg))

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        self.events.append(Event(level=level, code=code, stage=self.name, message=message, details=details))

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        raise AssertionError("adapter stages do not call services")

    @property
    def stopping(self) -> bool:
        return self.stop_event.is_set()

    def sleep(self, seconds: float) -> bool:
        return self.clock.sleep(seconds, self.stop_event)


def make_stage(cls: type[Stage], params: dict[str, Any], name: str = "dev") -> tuple[Stage, CollectingContext]:
    """Construct *cls* with validated *params* and a collecting context (setup not yet called)."""
    ctx = CollectingContext(name)
    return cls(ctx, cls.Params(**params)), ctx
