"""A device link that fails is closed and reopened by a later use, with exponential back-off
(plugins.devices.reconnect): what keeps a cell service up through a pulled camera cable."""

from __future__ import annotations

import pytest

from plugins.devices.reconnect import DeviceDownError, Reconnecting


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Device:
    """A fake camera: captures until `broken`; opening fails while the cable is out."""

    opened = 0
    cable_in = True

    def __init__(self) -> None:
        if not Device.cable_in:
            raise OSError("no device")
        Device.opened += 1
        self.broken = False
        self.closed = False

    def capture(self) -> str:
        if self.broken:
            raise RuntimeError("frame timeout")
        return "frame"


def make(clock: Clock) -> Reconnecting[Device]:
    Device.opened, Device.cable_in = 0, True
    return Reconnecting(Device, lambda d: setattr(d, "closed", True), what="cam", first_s=0.5, max_s=4.0, now=clock)


def test_a_failed_use_closes_the_device_and_the_next_use_reopens_it() -> None:
    clock = Clock()
    link = make(clock)
    first = link.connect()
    assert link.use(lambda d: d.capture()) == "frame"
    first.broken = True
    with pytest.raises(RuntimeError, match="frame timeout"):
        link.use(lambda d: d.capture())
    assert first.closed and link.device is None
    assert link.use(lambda d: d.capture()) == "frame"  # reopened at once: the cable was only glitching
    assert (Device.opened, link.reconnects) == (2, 1)


def test_reconnection_attempts_back_off_exponentially_and_reset_after_a_success() -> None:
    clock = Clock()
    link = make(clock)
    link.connect().broken = True
    with pytest.raises(RuntimeError):
        link.use(lambda d: d.capture())
    Device.cable_in = False
    waits = []
    for _ in range(5):
        with pytest.raises(OSError, match="no device"):  # an attempt is due: it fails
            link.use(lambda d: d.capture())
        with pytest.raises(DeviceDownError, match="next reconnection attempt in") as down:
            link.use(lambda d: d.capture())  # at once again: refused without touching the device
        waits.append(float(str(down.value).split(" in ")[1].split(" s")[0]))
        clock.t += waits[-1]
    assert waits == [0.5, 1.0, 2.0, 4.0, 4.0]  # doubling, capped at max_s
    Device.cable_in = True
    assert link.use(lambda d: d.capture()) == "frame"
    link.device.broken = True  # type: ignore[union-attr]
    with pytest.raises(RuntimeError):
        link.use(lambda d: d.capture())
    assert link.use(lambda d: d.capture()) == "frame"  # the back-off was reset by the success
