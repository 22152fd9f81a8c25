"""Ctrl-C for the long-running verbs (``vgr run``, ``vgr play``): a handler of the verb's own while
it runs, the previous one back afterwards."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any


@contextlib.contextmanager
def on_sigint(handler: Callable[[int, Any], None]) -> Iterator[None]:
    """*handler* answers SIGINT inside the block. Python takes signals on the main thread only: from
    any other thread (a test calling the verb, say) the block runs with the handler unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
