"""``DetachedContext``: enough of the engine to drive one stage by hand, with no bus and no run.

For code that needs a stage's exact behaviour outside a recipe run: benchmarks timing one stage's
handler, command-line verbs that ask one device stage a question. Publications and events are kept
in lists; service calls fail (a detached stage has nobody to call); time is a simulated clock; the
random generator is the one the stage would get in a run with the same seed.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from engine.clock import SimClock
from engine.messages import Event, Message
from engine.stage import ServiceError, Stage, StageContext


class DetachedContext(StageContext):
    """A StageContext for one stage outside a run (see the module docstring)."""

    def __init__(self, name: str, seed: int = 0, recipe_dir: Path | None = None) -> None:
        super().__init__(name, "detached", seed, SimClock(), logging.getLogger(f"vgr.detached.{name}"), recipe_dir)
        self.published: list[tuple[str, Message]] = []
        self.events: list[Event] = []

    def publish(self, port: str, msg: Message) -> None:
        self.published.append((port, msg))

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        self.events.append(Event(level=level, code=code, stage=self.name, message=message, details=details))

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        raise ServiceError(f"stage {self.name!r} runs detached: no service {client!r} to call")

    def has_client(self, client: str) -> bool:
        return False

    @property
    def stopping(self) -> bool:
        return False

    def sleep(self, seconds: float) -> bool:
        return self.clock.sleep(seconds)


def detached_stage(
    cls: type[Stage], name: str, params: dict[str, Any], seed: int = 0, recipe_dir: Path | None = None
) -> Stage:
    """Build and set up stage ``cls`` with recipe-style ``params``, detached from any run."""
    stage = cls(DetachedContext(name, seed, recipe_dir), cls.Params.model_validate(params))
    stage.setup()
    return stage
