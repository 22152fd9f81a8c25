"""``trigger``: a source of start signals, so that action stages are driven by data (and replayable).

An action stage (capture, guidance, docking) runs its job once per trigger message; in a live cell
the trigger comes from a PLC or an operator, in a recipe from this stage. Because the action stage
is then a consumer, not a source, replay re-runs it on the recorded triggers.
"""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import Field

from engine.messages import Request
from engine.stage import Stage, StageParams


class Trigger(Stage):
    """Emits `count` Request messages (command + args), `interval_s` apart on the run's clock."""

    type_name = "trigger"
    role = "source"
    outputs: ClassVar = {"out": Request}

    class Params(StageParams):
        count: int = Field(1, ge=0, le=1_000_000)
        interval_s: float = Field(0.0, ge=0.0, le=86_400.0, description="between triggers, s (at most a day)")
        command: str = "start"
        args: dict[str, Any] = Field(default_factory=dict)

    def run(self) -> None:
        p: Trigger.Params = self.params  # type: ignore[assignment]
        for i in range(p.count):
            if self.ctx.stopping:
                return
            self.ctx.publish("out", Request(command=p.command, args={**p.args, "index": i}))
            if p.interval_s and not self.ctx.sleep(p.interval_s):
                return
