"""The zenoh bus of one process: one session, vgr's key layout, streams, services, liveliness.

Key expressions (``<run>`` is the run id)::

    vgr/<run>/<stage>/<port>          data stream of an output port, one message per sample (pub/sub)
    vgr/<run>/_wire/<stage>/<port>    the same stream to vgr stages of other processes (engine.transport.wire)
    vgr/<run>/<stage>/srv/<service>   request/reply service of a stage (queryable)
    vgr/<run>/_ready/<stage>          liveliness: the stage is declared and listening
    vgr/<run>/_started/<process>      liveliness: the process has set up its stages and reads its inputs
    vgr/<run>/_active/<process>       liveliness: the process still has stages producing data
    vgr/<run>/_control                run-wide control (stop), published by any process
    vgr/<run>/_info/<process>         queryable: the process's topics, types and schemas (engine.transport.discovery)

Large payloads to the processes of this host go as descriptors of the sending port's own shared
memory (engine.transport.shm_views); :meth:`Bus.host_peers` says which processes of a run map it.

The default session is the embedded set-up: peer mode, multicast scouting off, and no listener
unless the run's processes need one (engine.transport.session_config; TLS and access control come from
there too). Stages of one process exchange message objects in-process
(engine.run.inbox); a stream goes through zenoh, encoded, when another process (on its ``_wire`` key,
see engine.transport.wire) or an external subscriber (on its public key) listens. Streams are reliable with
congestion control BLOCK: nothing is dropped.

Nothing may block zenoh's receive thread: it also delivers service replies, so a reader blocked
there would deadlock a stage waiting for a reply. A remote input's samples therefore go to a FIFO
channel of very large capacity, read by the port's pump thread (engine.run.remote_input.RemoteInput),
or, for a stage that can never wait there (it calls no service, its outputs stay in its process:
engine.run.remote_input.receive_thread_safe), to a callback on the receive thread itself
(:meth:`Bus.subscribe_direct`) that hands a message over only while the stage is idle and quick,
and queues it otherwise; service queries go to a callback that only appends to an unbounded queue.
(zenoh-python 1.10 runs a Python callback on a thread of its own, but feeds that thread through a
bounded channel: measured here, a callback blocked while a few hundred samples arrive stalls the
session's receive thread, service replies included. So no callback of ours ever blocks.)

A request may carry a :class:`CancelToken` (one per run): cancelling it (the run stops) ends every
request of the run still waiting for its reply at once, raising :class:`RequestCancelled` in its
caller, and refuses any new one before it is sent. The provider may still be working on an
abandoned query; its late reply goes nowhere.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import json
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any

import zenoh

from engine.messages.codec import Envelope, Kind, encode_envelope
from engine.recipe.model import ZenohSettings
from engine.transport.peers import Answer
from engine.transport.shm import ShmPool
from engine.transport.shm import session_entries as shm_entries
from engine.transport.shm_views import HostPeers

_open_buses: weakref.WeakSet[Bus] = weakref.WeakSet()


def data_key(run: str, stage: str, port: str) -> str:
    return f"vgr/{run}/{stage}/{port}"


def topic_of(stage: str, port: str) -> str:
    """The name of an output stream in recordings, the live view and ``vgr topics``."""
    return f"/{stage}/{port}"


def wire_key(run: str, stage: str, port: str) -> str:
    return f"vgr/{run}/_wire/{stage}/{port}"


def service_key(run: str, stage: str, service: str) -> str:
    return f"vgr/{run}/{stage}/srv/{service}"


def ready_key(run: str, stage: str) -> str:
    return f"vgr/{run}/_ready/{stage}"


def started_key(run: str, process: str) -> str:
    return f"vgr/{run}/_started/{process}"


def active_key(run: str, process: str) -> str:
    return f"vgr/{run}/_active/{process}"


def control_key(run: str) -> str:
    return f"vgr/{run}/_control"


def exchange_key(run: str, stage: str, client: str) -> str:
    return f"vgr/{run}/_svc/{stage}/{client}"


STOP_ENVELOPE = encode_envelope(Envelope(Kind.STOP, 0, 0, ""))
REMOTE_CHANNEL_CAPACITY = 1 << 22  # samples an input from another process may have waiting


def zenoh_config(settings: ZenohSettings, extra: dict[str, Any] | None = None) -> zenoh.Config:
    """zenoh's configuration from *settings* (``listen`` unset: no listener) and *extra*, a map of
    configuration paths to values (TLS, access control: engine.transport.session_config)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(settings.mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast_scouting))
    conf.insert_json5("listen/endpoints", json.dumps(list(settings.listen or [])))
    conf.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    for path, value in shm_entries(settings.shared_memory).items():  # (engine.transport.shm)
        conf.insert_json5(path, json.dumps(value))
    for path, value in (extra or {}).items():
        conf.insert_json5(path, json.dumps(value))
    return conf


class _Attachment:
    def __init__(self, raw: bytes) -> None:
        self._raw = raw

    def to_bytes(self) -> bytes:
        return self._raw


class StopMarker:
    """Looks like a zenoh Sample/Query carrying the STOP envelope."""

    attachment = _Attachment(STOP_ENVELOPE)
    payload = None

    def __enter__(self) -> StopMarker:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


TIMEOUT_PARAM = "vgr_timeout_ms"  # query parameter: how long the caller waits for the reply


def overdue_ms(query: Any, arrived_ns: int) -> float | None:
    """How long ago the caller of *query* (arrived at *arrived_ns*, monotonic) stopped waiting for
    its reply, or None while it still waits (or did not say how long it would). Measured from the
    query's arrival here, so the callers' and providers' clocks need not agree; the caller's timer
    started a transit time earlier (well under a millisecond on one machine)."""
    params = getattr(query, "parameters", None)
    raw = params.get(TIMEOUT_PARAM) if params is not None else None
    try:
        timeout_ms = float(raw)
    except (TypeError, ValueError):  # not said (None) or not a number
        return None
    late = (time.monotonic_ns() - arrived_ns) / 1e6 - timeout_ms
    return late if late > 0 else None


class Inbox:
    """Unbounded FIFO fed by a zenoh callback (never blocks zenoh's threads), read with
    ``recv_timed()``, which also says when each item arrived (see :func:`overdue_ms`)."""

    def __init__(self, key: str) -> None:
        self.key_expr = key
        self._items: collections.deque[Any] = collections.deque()
        self._cv = threading.Condition(threading.Lock())
        self.decl: Any = None

    def __call__(self, item: Any) -> None:
        arrived = time.monotonic_ns()
        with self._cv:
            self._items.append((arrived, item))
            self._cv.notify()

    def recv_timed(self) -> tuple[int, Any]:
        """(``time.monotonic_ns()`` when it arrived, next item); blocks until there is one."""
        with self._cv:
            while not self._items:
                self._cv.wait()
            return self._items.popleft()

    def wake(self) -> None:
        self(StopMarker())

    def __len__(self) -> int:
        return len(self._items)

    def undeclare(self) -> None:
        if self.decl is not None:
            self.decl.undeclare()


class LiveSet:
    """Liveliness tokens present, updated by a liveliness subscriber; ``wait`` for a change."""

    def __init__(self) -> None:
        self._keys: set[str] = set()
        self._cv = threading.Condition(threading.Lock())
        self._version = 0
        self.decl: Any = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._cv:
            if sample.kind == zenoh.SampleKind.DELETE:
                self._keys.discard(key)
            else:
                self._keys.add(key)
            self._version += 1
            self._cv.notify_all()

    def snapshot(self) -> tuple[set[str], int]:
        with self._cv:
            return set(self._keys), self._version

    def wait(self, version: int, timeout_s: float) -> None:
        """Return when the set changed after *version* (see :meth:`snapshot`) or after *timeout_s*."""
        with self._cv:
            self._cv.wait_for(lambda: self._version != version, timeout_s)

    def close(self) -> None:
        if self.decl is not None:
            with contextlib.suppress(Exception):
                self.decl.undeclare()
            self.decl = None


class BusError(RuntimeError):
    """The zenoh session could not be opened or used."""


def _open_error(settings: ZenohSettings, exc: Exception) -> str:
    """What a failed ``zenoh.open`` means: a unix socket another process holds (zenoh locks
    ``<socket>.lock``: "Unable to acquire lock") is a run of the same id on this host."""
    held = [e for e in settings.listen if e.startswith("unixsock-stream/")]
    if held and "acquire lock" in str(exc):
        return (
            f"another process of this user listens on {held[0].split('/', 1)[1]}: a run with the same run id "
            "and process is running on this host; give this one another --run-id (or stop the other)"
        )
    return f"cannot open zenoh session ({settings.mode}, listen={settings.listen}, connect={settings.connect}): {exc}"


class RequestCancelled(Exception):  # noqa: N818 - a cancellation, not a program error
    """The request's cancellation token was cancelled: no reply is awaited (none was sent when the token
    was cancelled before the request)."""


class CancelToken:
    """Cuts short every :meth:`Bus.request` that carries it: a zenoh ``CancellationToken`` (passing one
    costs nothing measurable, ~18 us per local round trip with or without) and a flag set *before* it
    is cancelled: zenoh closes the waiting requests' channels before its own ``is_cancelled`` turns
    true, and a request woken in between must not take the cancellation for a missing service."""

    def __init__(self) -> None:
        self.zenoh = zenoh.CancellationToken()
        self.cancelled = False

    def cancel(self) -> None:
        """Idempotent; safe from any thread (the SIGINT handler's included)."""
        self.cancelled = True
        self.zenoh.cancel()


class Bus:
    """One zenoh session and the declarations made on it; ``close()`` undeclares and closes."""

    def __init__(self, settings: ZenohSettings | None = None, extra: dict[str, Any] | None = None) -> None:
        self.settings = settings or ZenohSettings()
        try:
            self.session = zenoh.open(zenoh_config(self.settings, extra))
        except Exception as exc:
            raise BusError(_open_error(self.settings, exc)) from exc
        # this session's ZenohId, as zenoh names it in replies and source infos (it never changes)
        self.zid = str(self.session.zid())
        self._decls: list[Any] = []
        self._lock = threading.Lock()
        self._source_lock = threading.Lock()  # (the first source_info declares its entity once)
        self._source_id: Any = None  # an entity of this session, named in source infos
        self._source_sn = 0
        self.closed = False
        # the pool large payloads to other processes of this host are put from (engine.transport.shm)
        self.shm: ShmPool | None = ShmPool() if self.settings.shared_memory else None
        self._host_peers: dict[tuple[str, str], HostPeers] = {}  # (run, process) -> (engine.transport.shm_views)
        self.view_pools: list[Any] = []  # the ports' pools of views (engine.transport.shm_views.ViewPool)
        _open_buses.add(self)

    def host_peers(self, run: str, process: str) -> HostPeers:
        """Which processes of *run* map this host's shared memory (engine.transport.shm_views); made
        once per run and process, and *process* says it does when this session has shared memory on."""
        with self._lock:
            peers = self._host_peers.get((run, process))
            if peers is None:
                declare = self.settings.shared_memory
                peers = self._host_peers[(run, process)] = HostPeers(
                    self.session, run, process, self.zid, declare=declare
                )
            return peers

    # -- declarations ----------------------------------------------------------------------
    def _keep(self, decl: Any) -> Any:
        with self._lock:
            self._decls.append(decl)
        return decl

    def remote_publisher(self, key: str) -> zenoh.Publisher:
        """Publisher to other sessions only (stages here get messages in-process, see engine.run.inbox):
        reliable, congestion control BLOCK, so nothing is dropped. Not ``express``: measured over tcp
        loopback, express did not lower the one-way latency of paced messages and cut the throughput
        of small ones by 4x (every message its own batch)."""
        return self._keep(
            self.session.declare_publisher(
                key,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
                allowed_destination=zenoh.Locality.REMOTE,
            )
        )

    def subscribe_remote(self, key: str) -> tuple[zenoh.Subscriber, Any]:
        """Subscriber to other sessions' publications, and the FIFO channel its samples go to.

        zenoh's network thread only pushes each sample into the channel (Rust side: no GIL, no
        Python); the reader takes them with ``channel.recv()``, which blocks with the GIL released
        and raises once the subscriber is undeclared and the channel empty. The channel holds up to
        REMOTE_CHANNEL_CAPACITY samples (memory is taken as they queue, not up front); only a
        consumer that far behind would make zenoh's receive thread wait (TCP back-pressure)."""
        sub = self._keep(
            self.session.declare_subscriber(
                key, zenoh.handlers.FifoChannel(REMOTE_CHANNEL_CAPACITY), allowed_origin=zenoh.Locality.REMOTE
            )
        )
        return sub, sub.handler

    def subscribe_direct(self, key: str, callback: Callable[[zenoh.Sample], None]) -> zenoh.Subscriber:
        """Subscriber to other sessions' publications whose *callback* runs on zenoh's receive
        thread itself (no hand-over): it must never block, nor wait for anything zenoh delivers
        (a service reply), nor take long (every other message of that link waits meanwhile). Only
        engine.run.remote_input uses it, for the stages where that holds."""
        handler = zenoh.handlers.Callback(callback, indirect=False)
        return self._keep(self.session.declare_subscriber(key, handler, allowed_origin=zenoh.Locality.REMOTE))

    def subscribe(self, key: str, callback: Callable[[zenoh.Sample], None]) -> zenoh.Subscriber:
        """Subscriber calling *callback* on zenoh's thread (keep it short: observers, control)."""
        return self._keep(self.session.declare_subscriber(key, callback))

    def queryable(self, key: str) -> Inbox:
        """Queryable whose queries go to an :class:`Inbox` (never blocks zenoh's threads)."""
        box = Inbox(key)
        box.decl = self._keep(self.session.declare_queryable(key, box))
        return box

    def answer(self, key: str, payload: bytes) -> zenoh.Queryable:
        """Queryable replying *payload*, a constant, to every query on *key* (on zenoh's thread: a
        reply of bytes made beforehand never waits)."""

        def reply(query: zenoh.Query) -> None:
            with contextlib.suppress(Exception):  # the querier may have gone
                query.reply(key, payload)

        return self._keep(self.session.declare_queryable(key, reply))

    def token(self, key: str) -> zenoh.LivelinessToken:
        return self._keep(self.session.liveliness().declare_token(key))

    def watch_alive(self, key_expr: str) -> LiveSet:
        """Keys of the liveliness tokens matching *key_expr*, kept up to date as tokens come and go
        (a liveliness subscriber with history); ``close()`` it when done."""
        live = LiveSet()
        live.decl = self._keep(
            self.session.liveliness().declare_subscriber(
                key_expr, zenoh.handlers.Callback(live.on_sample, indirect=True), history=True
            )
        )
        return live

    def alive(self, key_expr: str, timeout_s: float = 1.0) -> set[str]:
        """Keys of the liveliness tokens currently matching *key_expr* (across all processes)."""
        replies = self.session.liveliness().get(key_expr, timeout=timeout_s)
        return {str(r.ok.key_expr) for r in replies if r.ok is not None}

    # -- request/reply ---------------------------------------------------------------------
    def request(
        self,
        key: str,
        payload: bytes,
        attachment: bytes,
        timeout_s: float,
        cancel: CancelToken | None = None,
    ) -> list[Answer]:
        """Send a query and return every reply that came, each with the ZenohId of the session that
        sent it (zenoh's ``Reply.replier_id``), once every queryable reached has answered: whether the
        one reply came from the stage's owner, and whether there was only one, is the caller's to
        check (engine.transport.peers.owners_answer). The query carries this session's id (``source_info``),
        which the provider records as its caller.

        Raises TimeoutError when nothing answered in time, LookupError when no service exists,
        RequestCancelled when *cancel* was cancelled before the reply came (or before the query left).
        A provider's error reply is an :class:`Answer` with its ``error``.
        """
        try:
            replies = self.session.get(
                f"{key}?{TIMEOUT_PARAM}={max(1, round(timeout_s * 1000))}",  # the provider skips it once we gave up
                payload=payload,
                attachment=attachment,
                timeout=timeout_s,
                # every queryable on the key, not zenoh's pick of one: a second replier is seen (and refused)
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,  # (zenoh's default keeps one reply per key)
                source_info=self.source_info(),
                cancellation_token=cancel.zenoh if cancel is not None else None,
            )
        except zenoh.ZError:
            if cancel is not None and cancel.cancelled:  # zenoh refuses a query whose token is cancelled
                raise RequestCancelled(f"{key}: not sent, cancelled") from None
            raise
        answers: list[Answer] = []
        for reply in replies:
            replier = str(reply.replier_id.zid) if reply.replier_id is not None else None
            if reply.ok is not None:
                att = reply.ok.attachment
                answers.append(Answer(reply.ok.payload.to_bytes(), att.to_bytes() if att is not None else b"", replier))
                continue
            err = reply.err.payload.to_bytes().decode(errors="replace") if reply.err is not None else "?"
            if err == "Timeout" and replier is None:  # zenoh's own: a queryable reached did not finish in time
                if answers:
                    break
                raise TimeoutError(f"no reply from {key} within {timeout_s:g} s")
            answers.append(Answer(b"", b"", replier, err))
        if answers:
            return answers
        if cancel is not None and cancel.cancelled:  # the token ended the wait: no reply came
            raise RequestCancelled(f"{key}: cancelled while waiting for the reply")
        raise LookupError(f"no service answers at {key} (is its stage running?)")

    def source_info(self) -> zenoh.SourceInfo:
        """What the engine's own puts and queries carry: this session's id (engine.transport.peers.sender_zid)."""
        if self._source_id is None:
            with self._source_lock:
                if self._source_id is None:
                    pub = self._keep(self.session.declare_publisher(f"vgr/_source/{self.zid}"))
                    self._source_id = pub.id
        with self._lock:
            self._source_sn = sn = self._source_sn + 1
        return zenoh.SourceInfo(self._source_id, sn)

    def put(self, key: str, payload: bytes, attachment: bytes | None = None) -> None:
        self.session.put(
            key,
            payload,
            attachment=attachment,
            congestion_control=zenoh.CongestionControl.BLOCK,
            source_info=self.source_info(),
        )

    # -- shutdown --------------------------------------------------------------------------
    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        with self._lock:
            decls, self._decls = self._decls, []
            peers, self._host_peers = list(self._host_peers.values()), {}
            pools = list(self.view_pools)  # (their counters stay readable for the run's summary)
        for pool in pools:
            pool.close()
        for p in peers:
            p.close()
        for d in reversed(decls):
            # already undeclared, or a reader still holds it: the session close below frees it
            with contextlib.suppress(Exception):
                d.undeclare()
        with contextlib.suppress(Exception):
            self.session.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@atexit.register
def _close_all() -> None:
    """Zenoh sessions must be closed before interpreter exit; this is the last resort."""
    for bus in list(_open_buses):
        bus.close()
