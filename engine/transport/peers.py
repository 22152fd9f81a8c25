"""Who belongs to a run: each process's zenoh session (ZenohId) and epoch, how each one left, and
which service reply, control message or caller comes from one of them.

Every process of a multi-process run declares one liveliness token::

    vgr/<run>/_peer/<process>/<zid>/<epoch>            while the process is in the run
    vgr/<run>/_peer/<process>/<zid>/<epoch>/started/<digest>
                                                       it passed its barrier with these peers
    vgr/<run>/_peer/<process>/<zid>/<epoch>/done       it ended in order (declared before it closes)

``<zid>`` is its zenoh session's id (what zenoh puts in ``Reply.replier_id`` and, for the engine's
own puts and queries, in ``source_info``); ``<epoch>`` is random per start of the process. ``<digest>``
names the epochs of every process when that process passed its start-up barrier
(:func:`members_digest`): a process that starts while the others already run with another epoch of
it is a restart (:meth:`PeerWatch.restarted_under_way`), refused unless the recipe says
``rejoin: true``.

One liveliness subscriber watches ``vgr/<run>/_peer/**``, so one process's tokens are seen in the
order it declared them: its ``done`` before the removal of its tokens when it closes. A process
whose token vanishes without ``done`` crashed or lost its zenoh lease (:attr:`PeerWatch.on_lost`).

What this does not do: zenoh lets a session put any ``source_info`` it likes, and a session may declare
any token. A peer that copies a member's ZenohId into its puts, or declares tokens for a process it
is not, gets past these checks; only zenoh's authentication and access control (the recipe's
``security:`` block) stop it. Replies are different: ``replier_id`` is set by zenoh, so a forged
reply is told apart from the owner's.
"""

from __future__ import annotations

import contextlib
import hashlib
import secrets
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh


def new_epoch() -> str:
    """A random id for one start of one process."""
    return secrets.token_hex(6)


def peer_key(run: str, process: str, zid: str, epoch: str) -> str:
    return f"vgr/{run}/_peer/{process}/{zid}/{epoch}"


def peer_process(key: str) -> str:
    """The process a key under :func:`peer_key` belongs to."""
    return key.split("/")[3]


def members_digest(epochs: dict[str, str]) -> str:
    """A short digest of ``process -> epoch`` for every process of the run (order-free)."""
    text = ";".join(f"{p}={e}" for p, e in sorted(epochs.items()))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class ForgedReply(Exception):  # noqa: N818 - a refusal, not a program error
    """A service answered from a session that does not own the stage, or answered twice; ``repliers``
    names the sessions that answered."""

    def __init__(self, message: str, repliers: list[str]) -> None:
        super().__init__(message)
        self.repliers = repliers


@dataclass
class Answer:
    """One reply to a request: its payload and attachment, or the error it carried; who sent it."""

    payload: bytes
    attachment: bytes
    replier: str | None  # the replying session's ZenohId (None: zenoh did not say)
    error: str | None = None


def owners_answer(answers: list[Answer], owner: str | None, where: str) -> Answer:
    """The one answer of the stage's *owner* session among *answers* (engine.transport.bus.Bus.request's: never
    empty, it raises when nothing answered).

    Raises ForgedReply when an answer came from another session (it is named) or when more than one
    answered: the caller then gets no result, so nothing moves on it."""
    if not answers:
        raise LookupError(f"{where}: no answer")
    repliers = sorted({a.replier or "unknown" for a in answers})
    strangers = sorted({a.replier or "unknown" for a in answers if owner is None or a.replier != owner})
    if strangers:
        raise ForgedReply(
            f"{where}: refused a reply from zenoh session {', '.join(strangers)}, "
            f"which does not own the stage (owner: {owner or 'unknown'})",
            repliers,
        )
    if len(answers) > 1:
        raise ForgedReply(f"{where}: {len(answers)} replies to one request; none is taken", repliers)
    return answers[0]


def sender_zid(sample: Any) -> str | None:
    """The ZenohId a sample or query says it comes from (its ``source_info``), or None."""
    info = getattr(sample, "source_info", None)
    if info is None:
        return None
    return str(info.source_id.zid)


@dataclass
class _Member:
    zid: str
    epoch: str
    done: bool = False
    started: str | None = None  # digest it started with
    gone: bool = False


@dataclass
class PeerWatch:
    """The run's processes as their ``_peer`` tokens show them (one liveliness subscriber).

    The first epoch seen of a process is the one accepted; a later one is accepted only when
    *rejoin* is True (:attr:`on_restart` is told either way). :attr:`on_lost` is called with a
    process whose accepted token vanished without its ``done`` marker. Callbacks run on zenoh's
    callback thread: keep them short."""

    run: str
    rejoin: bool = False
    on_lost: Callable[[str, str], None] = lambda process, zid: None
    on_restart: Callable[[str, str, str, bool], None] = lambda process, old, new, accepted: None
    _members: dict[str, _Member] = field(default_factory=dict)
    _others: dict[tuple[str, str], _Member] = field(default_factory=dict)  # refused epochs
    _cv: threading.Condition = field(default_factory=lambda: threading.Condition(threading.Lock()))
    decl: Any = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) < 6:
            return
        process, zid, epoch, rest = parts[3], parts[4], parts[5], parts[6:]
        put = sample.kind != zenoh.SampleKind.DELETE
        lost = restart = None
        with self._cv:
            m = self._members.get(process)
            if m is None or (m.gone and self.rejoin and put and (m.zid, m.epoch) != (zid, epoch)):
                old = m
                m = self._members[process] = _Member(zid, epoch)
                if old is not None:
                    restart = (process, old.epoch, epoch, True)
            elif (m.zid, m.epoch) != (zid, epoch):
                if put and not rest and (process, epoch) not in self._others:
                    self._others[(process, epoch)] = _Member(zid, epoch)
                    restart = (process, m.epoch, epoch, False)
                self._cv.notify_all()
                m = None
            if m is not None:
                if rest == ["done"] and put:
                    m.done = True
                elif len(rest) == 2 and rest[0] == "started" and put:
                    m.started = rest[1]
                elif not rest and not put:
                    m.gone = True
                    if not m.done:
                        lost = (process, zid)
                self._cv.notify_all()
        if restart is not None:
            self.on_restart(*restart)
        if lost is not None:
            self.on_lost(*lost)

    # -- questions ---------------------------------------------------------------------------
    def owner(self, process: str) -> str | None:
        """The ZenohId accepted for *process* (None until its token is seen)."""
        with self._cv:
            m = self._members.get(process)
            return m.zid if m is not None and not m.gone else None

    def process_of(self, zid: str | None) -> str | None:
        """The process whose accepted session is *zid*, or None (not a member of the run)."""
        if zid is None:
            return None
        with self._cv:
            return next((p for p, m in self._members.items() if m.zid == zid and not m.gone), None)

    def left_in_order(self, process: str, wait_s: float) -> bool:
        """*process*'s token is gone (a liveliness query said so): did it leave with ``done``? Waits
        up to *wait_s* for this watch to see the removal (its callbacks are queued); False when it
        left without ``done``, or when the removal is still unseen then (in doubt: lost)."""
        with self._cv:
            self._cv.wait_for(lambda: (m := self._members.get(process)) is not None and (m.done or m.gone), wait_s)
            m = self._members.get(process)
            return m is not None and m.done

    def last_zid(self, process: str) -> str | None:
        """The ZenohId last accepted for *process*, gone or not."""
        with self._cv:
            m = self._members.get(process)
            return m.zid if m is not None else None

    def epochs(self) -> dict[str, str]:
        with self._cv:
            return {p: m.epoch for p, m in self._members.items()}

    def wait_for(self, processes: set[str], deadline_s: float, what: str = "") -> set[str]:
        """Wait up to *deadline_s* seconds until every one of *processes* is seen (with its
        ``started`` marker when *what* is ``"started"``); returns those still missing."""

        def missing() -> set[str]:
            return {
                p
                for p in processes
                if p not in self._members or (what == "started" and self._members[p].started is None)
            }

        with self._cv:
            self._cv.wait_for(lambda: not missing(), deadline_s)
            return missing()

    def restarted_under_way(self, process: str, epoch: str) -> list[str]:
        """The other processes that passed their barrier with other members than those seen now, with
        *epoch* for *process* (an earlier epoch of it, typically): then *process* joins a run already
        under way."""
        epochs = {**self.epochs(), process: epoch}
        digest = members_digest(epochs)
        with self._cv:
            return sorted(p for p, m in self._members.items() if p != process and m.started and m.started != digest)

    def start(self, bus: Any) -> None:
        """Subscribe (with history) on *bus*'s session to the run's ``_peer`` tokens."""
        self.decl = bus.session.liveliness().declare_subscriber(
            f"vgr/{self.run}/_peer/**", zenoh.handlers.Callback(self.on_sample, indirect=True), history=True
        )

    def close(self) -> None:
        if self.decl is not None:
            with contextlib.suppress(Exception):  # the session closed first
                self.decl.undeclare()
            self.decl = None
