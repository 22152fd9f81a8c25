"""The stop signals for the long-running verbs (``vgr run``, ``vgr play``): Ctrl-C (SIGINT), SIGTERM
(what systemd, container runtimes and ``kill`` send) and SIGHUP (the terminal went away) all stop
the run as Ctrl-C does: motion halted first, the outcome ``interrupted`` (exit 130), the run's log
and recording completed. A handler of the verb's own while it runs, the previous ones back afterwards."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any

#: the signals that stop a run, and how the stop reason names each
STOP_SIGNALS: dict[signal.Signals, str] = {
    signal.SIGINT: "Ctrl-C",
    signal.SIGTERM: "SIGTERM",
    signal.SIGHUP: "SIGHUP",
}


def stop_reason(signum: int) -> str:
    """``interrupted (Ctrl-C)``, ``interrupted (SIGTERM)``, ...: the reason a stop signal gives."""
    return f"interrupted ({STOP_SIGNALS.get(signal.Signals(signum), signal.Signals(signum).name)})"


@contextlib.contextmanager
def on_stop_signals(handler: Callable[[int, Any], None]) -> Iterator[None]:
    """*handler* answers every signal of :data:`STOP_SIGNALS` inside the block. Python takes signals
    on the main thread only: from any other thread (a test calling the verb, say) the block runs
    with the handlers unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
