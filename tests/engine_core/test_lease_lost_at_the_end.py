"""A peer that loses its lease just as this process's stages settle is lost, not "ended".

When a process's session loses its zenoh lease (a cut link) or crashes, its ``_active`` token and
its ``_peer`` token go at once, but their two liveliness watchers are told on separate callback
threads, in either order. Seen from a process whose own stages have settled, the peer's stages
then look "ended" before the watch of ``_peer`` tokens has noticed anything; without the check in
engine.run.membership.Membership.ended_everywhere this process finished with exit 0 and no alarm
(tests/engine_core/test_security_netns.py saw it once under load). Here the tokens and the
liveliness query are played by hand, in that order.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import Any

import zenoh

from engine.run.membership import Membership
from engine.transport.bus import LiveSet, active_key

RUN = "cut"


class Sample(SimpleNamespace):
    """A liveliness sample as zenoh hands it to a watcher."""

    def __init__(self, key: str, put: bool = True) -> None:
        super().__init__(key_expr=key, kind=zenoh.SampleKind.PUT if put else zenoh.SampleKind.DELETE)


class Run:
    """The runner as the membership sees it."""

    def __init__(self) -> None:
        self.stop_event = threading.Event()
        self.stop_reason: str | None = None
        self.events: list[tuple[str, str]] = []

    def stop(self, reason: str, *, broadcast: bool = True) -> None:
        self.stop_reason = self.stop_reason or reason
        self.stop_event.set()

    def run_event(self, level: str, code: str, stage: str, message: str, **details: Any) -> None:
        self.events.append((level, code))


def membership(alive_now: set[str]) -> tuple[Membership, Run]:
    """The cell's membership of a two-process run, the vision peer accepted and active."""
    from engine.transport.peers import PeerWatch

    graph = SimpleNamespace(processes=lambda: ["cell", "vision"], recipe=SimpleNamespace(rejoin=False))
    bus = SimpleNamespace(zid="cellzid", alive=lambda key_expr, timeout_s=1.0: set(alive_now))
    run = Run()
    m = Membership(graph, "cell", RUN, 5.0, run, bus)  # type: ignore[arg-type]
    m.peers = PeerWatch(RUN, False, on_lost=m._peer_lost)
    m.peers.on_sample(Sample(f"vgr/{RUN}/_peer/vision/viszid/e1"))  # type: ignore[arg-type]
    m._active = LiveSet()
    m._active.on_sample(Sample(active_key(RUN, "vision")))  # type: ignore[arg-type]
    return m, run


def test_a_peer_whose_tokens_vanish_together_is_lost_even_if_its_active_token_is_seen_gone_first():
    m, run = membership(alive_now=set())  # the liveliness query: vision's _peer token is gone
    assert not m.ended_everywhere()  # vision still active
    m._active.on_sample(Sample(active_key(RUN, "vision"), put=False))  # type: ignore[union-attr, arg-type]
    # the _peer watch has not been told yet (its callback is still queued)
    assert not m.ended_everywhere()
    assert run.events == [("alarm", "peer_lost")] and m.lost_peer and "'vision'" in m.lost_peer
    assert run.stop_event.is_set()
    # the watch's own callback arrives afterwards: the loss is not said twice
    m.peers.on_sample(Sample(f"vgr/{RUN}/_peer/vision/viszid/e1", put=False))  # type: ignore[union-attr, arg-type]
    assert run.events == [("alarm", "peer_lost")]


def test_a_peer_that_left_with_done_has_ended():
    m, run = membership(alive_now=set())
    m.peers.on_sample(Sample(f"vgr/{RUN}/_peer/vision/viszid/e1/done"))  # type: ignore[union-attr, arg-type]
    m._active.on_sample(Sample(active_key(RUN, "vision"), put=False))  # type: ignore[union-attr, arg-type]
    assert m.ended_everywhere()
    assert run.events == [] and m.lost_peer is None


def test_a_peer_still_a_member_whose_stages_settled_has_ended():
    m, run = membership(alive_now={f"vgr/{RUN}/_peer/vision/viszid/e1"})
    m._active.on_sample(Sample(active_key(RUN, "vision"), put=False))  # type: ignore[union-attr, arg-type]
    assert m.ended_everywhere()
    assert run.events == []
