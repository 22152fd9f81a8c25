"""``vgr play``: a recording's data topics put back on zenoh at their recorded pace, as ``ros2 bag play``.

Each recorded message of an output port (``/<stage>/<port>``) is put on its public key
``vgr/<run>/<stage>/<port>`` with the envelope a live run gives it (docs/zenoh_layout.md: its recorded
seq, its source stamp, its type), in log-time order, the gap between two messages being the recorded
gap divided by ``rate``. The schedule is absolute (message *k* is due at start + its offset / rate),
so sleeping late once does not delay the rest. With ``--loop`` the seq numbers go on counting from
loop to loop (loop *k* adds *k* times the played span of the topic's seqs), so a subscriber that
drops a seq it has seen loses nothing; the stamps are the recorded ones each time, as ``ros2 bag
play --loop`` repeats header stamps. After the last message of the last loop each played topic gets
an end of stream, as a live port does.

It never drives a device. It publishes on the public data keys only: no ``_wire`` key (the one vgr
stages read from other processes), no ``_control`` (a run's stop), no query at all (so no service, no
robot command), and the engine's own records (``/_vgr/*``, service exchanges, deliveries) are not played.
A running stage therefore never receives what it plays; a foreign subscriber (a controller, a
dashboard, ``vgr topics echo``) does. The player answers ``vgr/<run>/_info/play`` like a run's
process (engine.transport.discovery, ``source: play``), so ``vgr topics`` finds it.

A plugin's message types (a guidance run's ``GuidanceResult``) are known once the plugins of the
recorded recipe are loaded (:func:`load_recorded_types`), as a replay loads them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from engine.messages import codec
from engine.messages.codec import Envelope, Kind
from engine.recording.reader import RecordedMessage, Recording
from engine.transport import discovery
from engine.transport.bus import Bus, data_key

PROCESS = "play"


class PlayError(ValueError):
    """The recording cannot be played as asked (no such topic, an empty selection, a bad rate)."""


def load_recorded_types(rec: Recording) -> None:
    """Load the plugins of *rec*'s recorded recipe (the installed ones and its ``plugins:``), so that
    the message types their stages publish are known to the codec."""
    from engine.plugin_manager import load_registry
    from engine.recipe.model import load_recipe

    plugins: list[str] = []
    if rec.recipe_text:
        plugins = load_recipe(
            f"{rec.path}#recipe", rec.overrides, text=rec.recipe_text, base=rec.recipe_dir or rec.path.parent
        ).recipe.plugins
    load_registry(plugins)


@dataclass(frozen=True)
class Selection:
    """What to play: *topics* (None: every data topic), from *start_s* to *end_s* seconds after the
    recording's first data message (None: from its start, to its end)."""

    topics: list[str] | None = None
    start_s: float | None = None
    end_s: float | None = None


def data_messages(rec: Recording) -> list[RecordedMessage]:
    """The recording's output-port messages (not the engine's own records), in log-time order."""
    return sorted((m for m in rec.messages() if m.stage and not m.stage.startswith("_")), key=lambda m: m.log_time)


def select(rec: Recording, sel: Selection) -> list[RecordedMessage]:
    msgs = data_messages(rec)
    if not msgs:
        raise PlayError(f"{rec.path} holds no data messages")
    t0 = msgs[0].log_time  # (of every topic: --start and --end count from the recording's first message)
    known = sorted({m.topic for m in msgs})
    if sel.topics is not None:
        wanted = {"/" + t.strip("/") for t in sel.topics}
        unknown = sorted(wanted - set(known))
        if unknown:
            raise PlayError(f"no topic {', '.join(unknown)} in {rec.path}; its topics: {', '.join(known)}")
        msgs = [m for m in msgs if m.topic in wanted]
    lo = t0 + round(sel.start_s * 1e9) if sel.start_s is not None else None
    hi = t0 + round(sel.end_s * 1e9) if sel.end_s is not None else None
    msgs = [m for m in msgs if (lo is None or m.log_time >= lo) and (hi is None or m.log_time <= hi)]
    if not msgs:
        raise PlayError("nothing to play between --start and --end of the topics chosen")
    return msgs


class Player:
    """Puts *messages* on *bus* under run id *run_id*; ``play()`` blocks until done or ``stop()``."""

    def __init__(self, bus: Bus, run_id: str, messages: list[RecordedMessage], rate: float = 1.0) -> None:
        if not rate > 0:
            raise PlayError(f"--rate {rate}: a rate is a positive factor of the recorded pace")
        self.bus, self.run_id, self.messages, self.rate = bus, run_id, messages, rate
        self._stop = threading.Event()
        self.published = 0
        self._pubs: dict[str, Any] = {}
        infos = []
        for m in messages:
            if m.topic not in self._pubs:
                self._pubs[m.topic] = bus.remote_publisher(data_key(run_id, m.stage, m.port))
                schema = codec.registry.get(m.type_name).SCHEMA
                infos.append(discovery.topic_info(run_id, m.stage, m.port, m.type_name, schema))
        discovery.announce(bus, run_id, PROCESS, infos, source="play")

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait until every played topic has a subscriber, at most *timeout_s*; True when they do."""
        deadline = time.monotonic() + timeout_s
        while not all(p.matching_status.matching for p in self._pubs.values()):
            if time.monotonic() >= deadline or self._stop.wait(0.02):
                return False
        return True

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def stop(self) -> None:
        """Ends ``play()`` before its next message (any thread, the SIGINT handler's included)."""
        self._stop.set()

    def play(self, loops: int = 1, on_message: Callable[[RecordedMessage], None] | None = None) -> int:
        """Play *loops* times (0: until ``stop()``); returns the messages put. Ends every topic."""
        if loops < 0:
            raise PlayError(f"--loop {loops}: play N >= 1 times, or 0 for until Ctrl-C")
        n = 0
        first = self.messages[0].log_time
        seqs = self._seq_ranges()
        span = {t: hi - lo + 1 for t, (lo, hi) in seqs.items()}
        last = {t: hi for t, (_, hi) in seqs.items()}  # the seq each topic put last
        while (loops == 0 or n < loops) and not self._stop.is_set():
            start = time.monotonic()
            for m in self.messages:
                due = start + (m.log_time - first) / 1e9 / self.rate
                if self._stop.wait(max(0.0, due - time.monotonic())):
                    break
                seq = last[m.topic] = m.seq + n * span[m.topic]  # a loop goes on counting: no seq twice
                env = codec.encode_envelope(codec.data_envelope(seq, m.publish_time, m.type_name))
                self._pubs[m.topic].put(m.payload, attachment=env)
                self.published += 1
                if on_message is not None:
                    on_message(m)
            n += 1
        for topic, pub in self._pubs.items():
            pub.put(b"", attachment=codec.encode_envelope(Envelope(Kind.EOS, last.get(topic, 0) + 1, 0, "")))
        return self.published

    def _seq_ranges(self) -> dict[str, tuple[int, int]]:
        """Per topic, the first and last seq played in one loop: loop *k* adds *k* times their span
        (last - first + 1) to the recorded seq, so the numbers keep rising from loop to loop, with
        no gap."""
        lo: dict[str, int] = {}
        hi: dict[str, int] = {}
        for m in self.messages:
            lo[m.topic] = min(lo.get(m.topic, m.seq), m.seq)
            hi[m.topic] = max(hi.get(m.topic, m.seq), m.seq)
        return {t: (lo[t], hi[t]) for t in lo}
