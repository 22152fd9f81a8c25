"""``RunScopedPort``: an output a streaming stage publishes from its service handler too, until its run ends.

The engine ends a streaming stage's outputs when the stage's ``run()`` returns (at once when the
stage streams nothing). A service request answered after that, e.g. a sampled tracker reading that
also goes on ``frames``, must then publish nothing. This class owns that state and its lock:
:meth:`RunScopedPort.publish` sends only while the run goes on, and :meth:`RunScopedPort.run` runs
the stage's stream and closes the port when the stream returns, however it returns. Used by the
tracker stages (``vive_tracker``, ``sim_tracker``) for their ``frames`` output.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from engine.messages import Message
from engine.stage import StageContext


class RunScopedPort:
    """Output *port* of the stage behind *ctx*, published to only until :meth:`run` returns."""

    def __init__(self, ctx: StageContext, port: str) -> None:
        self._ctx, self._port = ctx, port
        self._lock = threading.Lock()  # the stream thread and the service handler publish alike
        self._open = True

    def publish(self, msg: Message) -> None:
        """Publish *msg* on the port, or drop it when the stage's run has ended."""
        with self._lock:
            if self._open:
                self._ctx.publish(self._port, msg)

    def run(self, stream: Callable[[], None]) -> None:
        """Run *stream* (the stage's ``run`` body), then close the port: the engine ends it then."""
        try:
            stream()
        finally:
            with self._lock:
                self._open = False
