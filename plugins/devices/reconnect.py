"""A device link that comes back by itself: after a failure the device is closed, and the next use
opens it again, no sooner than an exponential back-off allows (``first_s``, doubling up to ``max_s``,
reset by a success). A cell service that runs for months meets a camera cable pulled and put back, a
USB hub that resets, a device that stops streaming: each such use fails (the cell answers
``camera_fault`` for that cycle) and a later one reconnects, without a restart of the service.

What a use that fails raises is the device's own error; while the back-off holds, :class:`DeviceDownError`
says when the next attempt is due. The clock is injectable (tests use a fake one).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Generic, TypeVar

D = TypeVar("D")
R = TypeVar("R")
log = logging.getLogger("vgr.devices.reconnect")


class DeviceDownError(ConnectionError):
    """The device is disconnected and the next reconnection attempt is not due yet."""


class Reconnecting(Generic[D]):
    """*open_device()* returns an open device, *close_device(d)* releases it; :meth:`use` runs a call on it."""

    def __init__(
        self,
        open_device: Callable[[], D],
        close_device: Callable[[D], None],
        *,
        what: str = "device",
        first_s: float = 0.5,
        max_s: float = 30.0,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        self._open, self._close, self.what = open_device, close_device, what
        self.first_s, self.max_s, self._now = first_s, max_s, now
        self.device: D | None = None
        self._backoff = 0.0
        self._next_try = 0.0
        self.reconnects = 0  # successful re-openings after a failure

    def connect(self) -> D:
        """Open the device now (the first time: a failure here is the caller's to report)."""
        self.device = self._open()
        return self.device

    def use(self, call: Callable[[D], R]) -> R:
        """*call(device)*, reconnecting first when the link is down and the back-off allows it."""
        if self.device is None:
            now = self._now()
            if now < self._next_try:
                wait = self._next_try - now
                raise DeviceDownError(f"{self.what} disconnected: next reconnection attempt in {wait:.1f} s")
            try:
                self.device = self._open()
            except Exception:
                self._back_off()
                raise
            self.reconnects += 1
            log.warning("%s reconnected (attempt after %.1f s back-off)", self.what, self._backoff)
        try:
            result = call(self.device)
        except Exception:
            self._drop()
            raise
        self._backoff = 0.0
        return result

    def _back_off(self) -> None:
        self._backoff = min(self.max_s, self._backoff * 2 if self._backoff else self.first_s)
        self._next_try = self._now() + self._backoff

    def _drop(self) -> None:
        """The link failed in use: close the device; the next use may reopen it at once (then back-off)."""
        device, self.device = self.device, None
        if device is not None:
            try:
                self._close(device)
            except Exception as exc:  # a device that failed may fail to close too
                log.debug("closing the failed %s: %s", self.what, exc)
        self._next_try = self._now() + self._backoff

    def close(self) -> None:
        device, self.device = self.device, None
        if device is not None:
            self._close(device)
