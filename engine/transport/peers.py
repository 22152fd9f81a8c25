"""Who belongs to a run: each process's zenoh session (ZenohId) and epoch, how each one left, and
which service reply, control message or caller comes from one of them.

Every process of a multi-process run declares one liveliness token::

    vgr/<run>/_peer/<process>/<zid>/<epoch>            while the process is in the run
    vgr/<run>/_peer/<process>/<zid>/<epoch>/started/<digest>
                                                       it passed its barrier with these peers
    vgr/<run>/_peer/<process>/<zid>/<epoch>/stopped    its run stopped (declared before ``done``)
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
``stopped`` is the token form of the stop a process broadcasts (engine.run.membership): a put sent
just before its session closes can be lost, a declaration is not (:attr:`PeerWatch.on_stopped`).

A token is a claim anyone connected may make, so it is taken only when this session's own links
agree (engine.transport.link_identity: the session on the process's endpoint, or the holder of its
certificate); a claim they contradict is refused and named (the alarm ``peer_impostor``,
engine.run.membership). What this does not do: zenoh lets a session put any ``source_info`` it likes.
A peer that copies a member's ZenohId into its puts gets past the control and caller checks without
``security:``; with it, a second session of one identity is seen on the links and stops the run.
Replies are different: ``replier_id`` is set by zenoh, so a forged reply is told apart from the
owner's.
"""

from __future__ import annotations

import contextlib
import hashlib
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from engine.transport.link_identity import ACCEPT, Verdict

RECHECK_S = 0.05  # how often a wait verifies again the claims held (a link coming up is no token change)


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
    stopped: bool = False
    started: str | None = None  # digest it started with
    gone: bool = False


def _mark(m: _Member, rest: list[str], put: bool) -> None:
    """Apply one token change of *m*'s session: its ``done``, ``stopped``, ``started/<digest>``, its removal."""
    if rest == ["done"] and put:
        m.done = True
    elif rest == ["stopped"] and put:
        m.stopped = True
    elif len(rest) == 2 and rest[0] == "started" and put:
        m.started = rest[1]
    elif not rest and not put:
        m.gone = True


@dataclass
class PeerWatch:
    """The run's processes as their ``_peer`` tokens show them (one liveliness subscriber).

    A token is a claim; *verify* (engine.transport.link_identity: this session's links) decides
    whether its session is that process: accepted, refused (:attr:`on_refused` is told why) or not
    known yet (held, and checked again by :meth:`recheck`, which :meth:`wait_for` and
    :meth:`owner` call while claims are held). The first accepted epoch of a process is the run's;
    a later one is accepted only when *rejoin* is True (:attr:`on_restart` is told either way).
    :attr:`on_lost` is called with a process whose accepted token vanished without its ``done``
    marker; :attr:`on_stopped` with a process whose accepted session says its run stopped.
    Callbacks run on zenoh's callback thread: keep them short."""

    run: str
    rejoin: bool = False
    on_lost: Callable[[str, str], None] = lambda process, zid: None
    on_stopped: Callable[[str], None] = lambda process: None
    on_restart: Callable[[str, str, str, bool], None] = lambda process, old, new, accepted: None
    verify: Callable[[str, str], Verdict] = lambda process, zid: ACCEPT
    on_refused: Callable[[str, str, str], None] = lambda process, zid, why: None
    # this process and its session: a token of its name from another session is not taken for it
    # (an earlier or later start of it, which the others' epochs show, or an impostor)
    own: tuple[str, str] | None = None
    _members: dict[str, _Member] = field(default_factory=dict)
    _others: dict[tuple[str, str], _Member] = field(default_factory=dict)  # refused epochs
    _held: dict[tuple[str, str], tuple[str, _Member]] = field(default_factory=dict)  # (zid, epoch) -> unverified
    _impostors: set[tuple[str, str]] = field(default_factory=set)  # (zid, epoch) refused by verify
    _cv: threading.Condition = field(default_factory=lambda: threading.Condition(threading.Lock()))
    decl: Any = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) < 6:
            return
        process, zid, epoch, rest = parts[3], parts[4], parts[5], parts[6:]
        if self.own is not None and process == self.own[0] and zid != self.own[1]:
            return
        put = sample.kind != zenoh.SampleKind.DELETE
        with self._cv:
            if (zid, epoch) in self._impostors:
                return
            held = self._held.get((zid, epoch))
            if held is not None:  # not verified yet: its markers wait with it
                _mark(held[1], rest, put)
                if not rest and not put:
                    del self._held[(zid, epoch)]
                return
            known = self._members.get(process)
            seen = (known is not None and (known.zid, known.epoch) == (zid, epoch)) or (process, epoch) in self._others
        if seen or not put:
            self._update(process, zid, epoch, rest, put)
            return
        # a session not seen before (its markers may come before its token: history is unordered)
        claim = _Member(zid, epoch)
        _mark(claim, rest, put)
        self._admit(process, claim, fresh=True)

    def _admit(self, process: str, claim: _Member, *, fresh: bool) -> None:
        """A claim: verified (outside the lock: it asks the session), then held, refused or taken
        as the process. Not *fresh*: a held one checked again, unless its token went meanwhile."""
        verdict = self.verify(process, claim.zid)
        restart = None
        with self._cv:
            key = (claim.zid, claim.epoch)
            if not fresh and key not in self._held:
                return  # its token went while it was checked
            if verdict.pending:
                self._held[key] = (process, claim)
                return
            self._held.pop(key, None)
            if not verdict.accepted:
                self._impostors.add(key)
            else:
                restart = self._take(process, claim)
            self._cv.notify_all()
        if verdict.refusal:
            self.on_refused(process, claim.zid, verdict.refusal)
        if restart is not None:
            self.on_restart(*restart)

    def _take(self, process: str, claim: _Member) -> tuple[str, str, str, bool] | None:
        """A verified token (the lock held): the process's member, a rejoin, or a refused epoch."""
        m = self._members.get(process)
        if m is None or (m.gone and self.rejoin and (m.zid, m.epoch) != (claim.zid, claim.epoch)):
            self._members[process] = claim
            return None if m is None else (process, m.epoch, claim.epoch, True)
        if (m.zid, m.epoch) != (claim.zid, claim.epoch) and (process, claim.epoch) not in self._others:
            self._others[(process, claim.epoch)] = claim
            return (process, m.epoch, claim.epoch, False)
        return None

    def _update(self, process: str, zid: str, epoch: str, rest: list[str], put: bool) -> None:
        """A marker of, or the removal of, a token already seen."""
        lost = stopped = None
        with self._cv:
            m = self._members.get(process)
            if m is not None and (m.zid, m.epoch) == (zid, epoch):
                was_stopped = m.stopped
                _mark(m, rest, put)
                if not rest and not put and not m.done:
                    lost = (process, zid)
                if m.stopped and not was_stopped:
                    stopped = process
            self._cv.notify_all()
        if stopped is not None:
            self.on_stopped(stopped)
        if lost is not None:
            self.on_lost(*lost)

    def recheck(self) -> None:
        """Verify again the claims held until this session's links could say (see :meth:`_admit`)."""
        with self._cv:
            held = list(self._held.values())
        for process, claim in held:
            self._admit(process, claim, fresh=False)

    # -- questions ---------------------------------------------------------------------------
    def owner(self, process: str) -> str | None:
        """The ZenohId accepted for *process* (None until its token is seen and verified)."""
        if self._held:
            self.recheck()
        with self._cv:
            m = self._members.get(process)
            return m.zid if m is not None and not m.gone else None

    def process_of(self, zid: str | None, *, gone: bool = False) -> str | None:
        """The process whose accepted session is *zid*, or None (not a member of the run). With
        *gone*, also a session that has left: a message it sent just before may arrive after its
        token's removal (zenoh sends declarations at a higher priority than data)."""
        if zid is None:
            return None
        if self._held:
            self.recheck()
        with self._cv:
            return next((p for p, m in self._members.items() if m.zid == zid and (gone or not m.gone)), None)

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

    def wait_for(
        self, processes: set[str], deadline_s: float, what: str = "", stop: threading.Event | None = None
    ) -> set[str]:
        """Wait up to *deadline_s* seconds until every one of *processes* is seen (with its
        ``started`` marker when *what* is ``"started"``), or *stop* is set; returns those still
        missing. A process whose claim is held (not verified yet) is missing."""

        def missing() -> set[str]:
            return {
                p
                for p in processes
                if p not in self._members or (what == "started" and self._members[p].started is None)
            }

        deadline = time.monotonic() + deadline_s
        while True:
            self.recheck()
            with self._cv:
                left = deadline - time.monotonic()
                # (held claims are verified again every RECHECK_S: a link coming up is no token change)
                done = self._cv.wait_for(lambda: not missing(), min(left, RECHECK_S))
                if done or left <= 0 or (stop is not None and stop.is_set()):
                    return missing()

    def held(self) -> dict[str, list[str]]:
        """The claims not verified yet: process -> the sessions claiming it."""
        with self._cv:
            out: dict[str, list[str]] = {}
            for process, claim in self._held.values():
                out.setdefault(process, []).append(claim.zid)
            return out

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
