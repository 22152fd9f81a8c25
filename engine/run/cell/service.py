"""The cell service: a held-open run whose jobs arrive as controller requests (``vgr serve``).

:class:`CellService` declares one zenoh queryable per API command (``vgr/<cell>/api/<command>``,
engine.run.cell.protocol) on the run's session, once every stage is set up, and answers each:

* a job command (``locate``, ``guide``) runs one *cycle*: the request document goes, as a
  :class:`~engine.messages.Request`, to the stage service the recipe's ``serve.commands`` names; its
  :class:`~engine.messages.CellReply` comes back as the reply document, with the cycle number and the
  time per part (the cycle, and each service the job called). One cycle at a time: a job request
  while a cycle runs is answered ``busy`` at once (not queued: a controller that waits on a queue
  cannot tell a slow cell from a dead one). Each request id is answered once: the same id again gets
  the same reply (kept for the last ``serve.remember`` ids), also while its cycle still runs (the
  repeat waits for it), never a second capture;
* ``status``: ready or not, cycle counters by status, the last error, takt-time figures
  (engine.run.cell.takt), the versions of the files in use, memory and open files;
* ``reload``: new parameters (``set``: ``{"stage.param": value}``) or re-read files, for solver and
  action stages: the new stages are built and set up while cycles go on, then swapped in between two
  cycles, all or nothing; the recording rolls so each cycle file holds one configuration;
* ``stop``: as a stop signal (:meth:`begin_stop`).

The request the service sends to the job stage is recorded as a service exchange of caller ``_cell``
(topic ``/_cell/_svc/<command>``); replay answers it with the re-run job stage and compares the reply
(engine.recording.replay). Before each cycle the re-run stages' random generators are reset to their
start, so a cycle replays alone, from its own file (engine.recording.cycle_files).

A stop (:meth:`begin_stop`: SIGINT, SIGTERM, ``stop``): job requests are answered ``stopping`` from
then on; the cycle under way has ``STOP_GRACE_S`` to end, then the run is released (an orderly end,
exit 0); a cycle still running then is cut short by the runner's stop (its calls cancelled, devices
halted first; exit 130).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from engine.graph import ServiceEdge
from engine.messages import CellReply, Request
from engine.recipe.model import ServeSettings
from engine.run.cell import protocol
from engine.run.cell.codes import Status
from engine.run.cell.takt import TaktTimes
from engine.run.runner import Observer, Runner
from engine.run.service_call import exchange
from engine.run.stage_host import ServiceCall
from engine.stage import PLAYBACK_ROLES, stage_rng
from engine.transport.bus import StopMarker
from engine.transport.peers import ForgedReply

log = logging.getLogger("vgr.cell")
CALLER = "_cell"  # the caller name of the service's requests in recordings
STOP_GRACE_S = 5.0  # how long a stop lets the cycle under way finish
REPEAT_WAIT_S = 60.0  # how long a repeated request waits for its first one's cycle


@dataclass
class _Cycle:
    number: int
    command: str
    request_id: str
    started: float = field(default_factory=time.perf_counter)
    parts_s: dict[str, float] = field(default_factory=dict)


class CellService(Observer):
    """Serves the API of cell ``settings.cell`` on *runner*'s session (see the module docstring).

    *reload* builds the swap a ``reload`` request asks for (engine.run.cell.reload); *on_cycle* sees
    each answered cycle's log line (the service's ``cycles.jsonl``)."""

    def __init__(
        self,
        runner: Runner,
        settings: ServeSettings,
        *,
        reload: Callable[[dict[str, Any]], tuple[str, Callable[[], None]]] | None = None,
        on_cycle: Callable[[dict[str, Any]], None] | None = None,
        status_extra: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        self.runner = runner
        self.settings = settings
        self.cell = settings.cell
        self._reload = reload
        self._on_cycle = on_cycle
        self._status_extra = status_extra
        self._on_ready: list[Callable[[], None]] = []  # see when_ready()
        self.stopping = False
        self.stop_reason = ""
        self.cut_short = False  # a stop ended the run while a cycle still ran
        self.cycles = 0
        self.by_status: dict[str, int] = {}
        self.last_error: dict[str, Any] | None = None
        self.reloads = 0
        self.takt = TaktTimes()
        self.started_at = time.time()
        self._cycle_lock = threading.Lock()  # held for the whole of a cycle (and a reload's swap)
        self._cycle: _Cycle | None = None
        self._parts_lock = threading.Lock()
        self._replies: OrderedDict[str, tuple[str, dict[str, Any]]] = OrderedDict()  # id -> (command, reply)
        self._inflight: dict[str, threading.Event] = {}
        self._ids_lock = threading.Lock()
        self._inboxes: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._worker_jobs: list[tuple[str, dict[str, Any], Any]] = []
        self._worker_cv = threading.Condition()
        self._closed = False
        runner.observers.append(self)
        runner.before_shutdown.append(self.close)

    # -- life ----------------------------------------------------------------------------------
    def start(self) -> None:
        """Wait (in a thread) until the run is ready, then declare the API and serve it."""
        self._spawn("vgr:cell.start", self._start_when_ready)

    def _start_when_ready(self) -> None:
        while not self.runner.ready.wait(0.1):
            if self.runner.stop_event.is_set():
                return
        bus = self.runner.bus
        for command in protocol.COMMANDS:
            inbox = bus.queryable(protocol.api_key(self.cell, command))
            self._inboxes.append(inbox)
            self._spawn(f"vgr:cell.{command}", self._pump, command, inbox)
        self._spawn("vgr:cell.worker", self._work)
        self._alive = bus.token(protocol.alive_key(self.cell))
        log.info("cell %s serving %s", self.cell, ", ".join(protocol.COMMANDS))
        self.runner.run_event("info", "cell_ready", "", f"cell {self.cell} ready", cell=self.cell)
        for ready in self._on_ready:
            ready()

    def when_ready(self, call: Callable[[], None]) -> None:
        """*call()* once the API is declared and serving (before start(): e.g. the first cycle file)."""
        self._on_ready.append(call)

    def _spawn(self, name: str, target: Callable[..., None], *args: Any) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        self._threads.append(t)
        t.start()

    def close(self) -> None:
        """Stop answering (after the run ended): the pumps and the worker end."""
        self.stopping = True
        alive = getattr(self, "_alive", None)
        if alive is not None:
            alive.undeclare()
        for inbox in self._inboxes:
            inbox.wake()
            inbox.undeclare()
        with self._worker_cv:
            self._closed = True
            self._worker_cv.notify_all()
        for t in self._threads:
            t.join(2.0)

    def begin_stop(self, reason: str) -> None:
        """No new cycle; the one under way has STOP_GRACE_S, then the run ends (see the module docstring)."""
        if self.stopping:
            return
        self.stopping, self.stop_reason = True, reason
        self.runner.run_event("info", "cell_stopping", "", f"cell {self.cell} stopping: {reason}", reason=reason)
        threading.Thread(target=self._end_run, name="vgr:cell.stop", daemon=True).start()

    def _end_run(self) -> None:
        if self._cycle_lock.acquire(timeout=STOP_GRACE_S):
            self._cycle_lock.release()
            self.runner.release()
            return
        self.cut_short = True
        cycle = self._cycle.number if self._cycle is not None else 0
        self.runner.stop(f"{self.stop_reason}: cycle {cycle} cut short after {STOP_GRACE_S:g} s")

    # -- requests ------------------------------------------------------------------------------
    def _pump(self, command: str, inbox: Any) -> None:
        while True:
            _, query = inbox.recv_timed()
            if isinstance(query, StopMarker):
                return
            payload = query.payload.to_bytes() if query.payload is not None else b""
            if command in protocol.JOB_COMMANDS:
                self._take_job(command, payload, query)
            else:
                with query:
                    self._reply(query, self.handle_bytes(command, payload))

    def _reply(self, query: Any, doc: dict[str, Any]) -> None:
        try:
            query.reply(query.key_expr, protocol.encode(doc))
        except Exception as exc:  # the caller gave up, the session closes: nothing to do about it
            log.debug("reply to %s not sent: %s", query.key_expr, exc)

    def _take_job(self, command: str, payload: bytes, query: Any) -> None:
        """A job request from zenoh: answered at once when it cannot run, else handed to the worker
        (the pump goes on reading, so a request meanwhile is answered ``busy``, not left waiting).
        A repeat of a request whose cycle still runs waits for it in a thread of its own, not in the pump."""
        doc, refused = self._parse_job(command, payload)
        if refused is not None:
            with query:
                self._reply(query, refused)
            return
        with self._ids_lock:
            repeat_in_flight = doc["id"] in self._inflight
        if repeat_in_flight:
            threading.Thread(
                target=self._answer_job, args=(command, doc, query), name="vgr:cell.repeat", daemon=True
            ).start()
            return
        self._answer_job(command, doc, query)

    def _answer_job(self, command: str, doc: dict[str, Any], query: Any) -> None:
        early = self._admit(command, doc)
        if early is not None:
            with query:
                self._reply(query, early)
            return
        with self._worker_cv:
            self._worker_jobs.append((command, doc, query))
            self._worker_cv.notify()

    def _work(self) -> None:
        """Thread: runs the admitted zenoh job requests, one at a time, until the service is closed."""
        while True:
            with self._worker_cv:
                while not self._worker_jobs and not self._closed:
                    self._worker_cv.wait(0.5)
                if not self._worker_jobs:
                    return
                command, doc, query = self._worker_jobs.pop(0)
            with query:
                try:
                    reply = self._run_admitted(command, doc)
                except Exception as exc:  # the service itself failed: said, and it goes on
                    log.exception("cycle of %s %s failed", command, doc.get("id"))
                    reply = self._reply_doc(command, doc.get("id"), "fault", f"{type(exc).__name__}: {exc}")
                self._reply(query, reply)

    def handle_bytes(self, command: str, payload: bytes) -> dict[str, Any]:
        """The reply document to *payload* (a request as sent), any command, on the caller's thread."""
        if command in protocol.JOB_COMMANDS:
            doc, refused = self._parse_job(command, payload)
            if refused is not None:
                return refused
            early = self._admit(command, doc)
            return early if early is not None else self._run_admitted(command, doc)
        try:
            doc = protocol.parse_request(command, payload)
        except protocol.InvalidRequest as exc:
            return protocol.invalid(self.cell, command, None, str(exc))
        rid = doc.get("id")
        if command == "status":
            return self._reply_doc(command, rid, "ok", "ready" if self.ready else "not ready", result=self.status())
        if command == "stop":
            self.begin_stop("a stop request")
            return self._reply_doc(command, rid, "ok", "stopping: no new cycle; the one under way finishes")
        return self._reload_request(rid, doc)

    def handle(self, command: str, doc: dict[str, Any]) -> dict[str, Any]:
        """The reply document to request document *doc* (what a gateway calls, on its own thread)."""
        try:
            payload = protocol.encode(doc)
        except (TypeError, ValueError) as exc:
            return protocol.invalid(self.cell, command, doc.get("id"), f"the request is not JSON: {exc}")
        return self.handle_bytes(command, payload)

    @property
    def ready(self) -> bool:
        return self.runner.ready.is_set() and not self.stopping and not self.runner.stop_event.is_set()

    def _reply_doc(self, command: str, rid: str | None, status: str, message: str, **kw: Any) -> dict[str, Any]:
        return protocol.reply_doc(self.cell, command, rid, status, message, **kw)

    def _parse_job(self, command: str, payload: bytes) -> tuple[dict[str, Any], dict[str, Any] | None]:
        """(the request document, None), or ({}, the reply) to one that cannot be taken or that
        names a command this cell does not serve."""
        try:
            doc = protocol.parse_request(command, payload)
        except protocol.InvalidRequest as exc:
            return {}, protocol.invalid(self.cell, command, _peek_id(payload), str(exc))
        if command not in self.settings.commands:
            served = ", ".join(self.settings.commands)
            why = f"this cell does not {command} (it serves {served})"
            return {}, self._reply_doc(command, doc["id"], "invalid_request", why)
        return doc, None

    def _admit(self, command: str, doc: dict[str, Any]) -> dict[str, Any] | None:
        """The reply to a job request that does not run a cycle now, else None: the request is
        admitted and holds the cycle lock until :meth:`_run_admitted` releases it."""
        rid = doc["id"]
        while True:
            with self._ids_lock:
                known = self._replies.get(rid)
                waiting = self._inflight.get(rid)
                if known is None and waiting is None:
                    if self.stopping or not self.runner.ready.is_set():
                        why = (
                            "stopping: no new cycle starts"
                            if self.stopping
                            else "not ready yet: the stages are starting"
                        )
                        return self._reply_doc(command, rid, "stopping" if self.stopping else "busy", why)
                    if not self._cycle_lock.acquire(blocking=False):
                        busy = self._cycle
                        what = f"cycle {busy.number} ({busy.command} {busy.request_id})" if busy else "a reload"
                        return self._reply_doc(command, rid, "busy", f"busy with {what}: ask again after it")
                    self._inflight[rid] = threading.Event()
                    return None
            if known is not None:
                first_command, reply = known
                if first_command != command:
                    msg = f"id {rid!r} was a {first_command} request: a new request needs a new id"
                    return self._reply_doc(command, rid, "invalid_request", msg)
                return reply
            if not waiting.wait(REPEAT_WAIT_S):  # (a repeat while its first request's cycle still runs)
                return self._reply_doc(command, rid, "busy", f"id {rid!r}: its first request is still running")

    def _run_admitted(self, command: str, doc: dict[str, Any]) -> dict[str, Any]:
        rid = doc["id"]
        try:
            reply = self._cycle_of(command, doc)
        finally:
            with self._parts_lock:
                self._cycle = None
            with self._ids_lock:
                done = self._inflight.pop(rid)
            self._cycle_lock.release()
        done.set()
        return reply

    # -- one cycle -----------------------------------------------------------------------------
    def _cycle_of(self, command: str, doc: dict[str, Any]) -> dict[str, Any]:
        rid = doc["id"]
        self.cycles += 1
        cycle = _Cycle(self.cycles, command, rid)
        self._reset_rerun_stages()
        with self._parts_lock:
            self._cycle = cycle
        status, message, result = self._call_job(command, doc, cycle)
        timing = {"total": (time.perf_counter() - cycle.started) * 1e3}
        with self._parts_lock:
            timing.update({part: s * 1e3 for part, s in cycle.parts_s.items()})
        reply = self._reply_doc(command, rid, status, message, cycle=cycle.number, result=result, timing_ms=timing)
        self.by_status[status] = self.by_status.get(status, 0) + 1
        if status != "ok":
            self.last_error = {"cycle": cycle.number, "id": rid, "status": status, "message": message}
        self.takt.add(timing)
        with self._ids_lock:
            self._replies[rid] = (command, reply)
            while len(self._replies) > self.settings.remember:
                self._replies.popitem(last=False)
        info = {"cycle": cycle.number, "command": command, "id": rid, "status": status, "code": reply["code"]}
        self.runner.run_event(
            "info" if status == "ok" else "warning",
            "cycle",
            "",
            f"cycle {cycle.number}: {status}: {message}",
            cycle=cycle.number,
            command=command,
            id=rid,
            status=status,
            timing_ms=timing,
        )
        if self._on_cycle is not None:
            self._on_cycle({**info, "message": message, "timing_ms": timing, "time_utc": time.time()})
        return reply

    def _reset_rerun_stages(self) -> None:
        """Each re-run stage's random generator back to its start: a cycle is what its replay is."""
        for name, rt in self.runner.runtimes.items():
            if rt.node.cls.role not in PLAYBACK_ROLES and not rt.node.cls.is_source():
                rt.rng = stage_rng(self.runner.seed, name)

    def _call_job(self, command: str, doc: dict[str, Any], cycle: _Cycle) -> tuple[str, str, dict[str, Any]]:
        """The job stage's (status, message, result), recorded as a service exchange of ``_cell``."""
        provider, _, service = self.settings.commands[command].partition(".")  # type: ignore[index]
        request = Request(command=command, args=doc)
        request.stamp_ns = self.runner.clock.now_ns()
        request.seq = cycle.number
        timeout = self.settings.cycle_timeout_s
        where = f"{provider}.{service}"
        observers = [obs for obs in self.runner.observers if obs is not self]
        try:
            reply = exchange(
                self.runner, CALLER, ServiceEdge(CALLER, command, provider, service), request, timeout, observers
            )
        except TimeoutError:
            return "fault", f"{where}: no reply within {timeout:g} s (serve.cycle_timeout_s)", {}
        except RuntimeError as exc:  # the job stage's error reply
            return "fault", f"{where} failed: {exc}", {}
        except ForgedReply as exc:  # nothing is taken from it: no result, no motion
            self.runner.run_event("alarm", "forged_reply", "", str(exc), service=where, repliers=exc.repliers)
            return "fault", str(exc), {}
        except Exception as exc:  # cancelled by a stop, the provider gone, a reply that does not decode, ...
            status = "stopping" if self.runner.stop_event.is_set() else "fault"
            return status, f"{where}: {type(exc).__name__}: {exc}", {}
        if not isinstance(reply, CellReply):
            return "fault", f"{where} replied {type(reply).__name__}, not CellReply", {}
        status = reply.status if reply.status in Status.__members__ else "fault"
        return status, reply.message, dict(reply.result)

    def on_service(self, call: ServiceCall) -> None:
        """A call the job made during the cycle: its time goes to the cycle's part ``provider.service``."""
        with self._parts_lock:
            cycle = self._cycle
            if cycle is not None and call.stage != CALLER:
                part = f"{call.edge.provider}.{call.edge.service}"
                cycle.parts_s[part] = cycle.parts_s.get(part, 0.0) + call.elapsed_s

    # -- status and reload -----------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        takt = self.takt.figures()
        doc: dict[str, Any] = {
            "ready": self.ready,
            "state": "stopping" if self.stopping else ("serving" if self.runner.ready.is_set() else "starting"),
            "cycles": self.cycles,
            "by_status": dict(self.by_status),
            "last_error": self.last_error,
            "reloads": self.reloads,
            "takt_ms": takt.get("total", {}),
            "takt_parts_ms": {k: v for k, v in takt.items() if k != "total"},
            "uptime_s": time.time() - self.started_at,
            "commands": dict(self.settings.commands),
            "pid": os.getpid(),
        }
        if self._status_extra is not None:
            doc.update(self._status_extra())
        return doc

    def _reload_request(self, rid: str | None, doc: dict[str, Any]) -> dict[str, Any]:
        if self._reload is None:
            return self._reply_doc("reload", rid, "invalid_request", "this service cannot reload")
        changes = doc.get("set", {})
        if not isinstance(changes, dict) or not all(isinstance(k, str) for k in changes):
            return self._reply_doc("reload", rid, "invalid_request", "set: an object of 'stage.param': value")
        if self.stopping:
            return self._reply_doc("reload", rid, "stopping", "stopping: nothing is reloaded")
        try:
            summary, swap = self._reload(changes)  # new stages built and set up; cycles go on meanwhile
        except ValueError as exc:
            return self._reply_doc("reload", rid, "invalid_request", f"nothing reloaded: {exc}")
        except Exception as exc:
            log.exception("reload failed")
            return self._reply_doc("reload", rid, "fault", f"nothing reloaded: {type(exc).__name__}: {exc}")
        with self._cycle_lock:  # between two cycles
            swap()
            self.reloads += 1
        self.runner.run_event("info", "cell_reload", "", f"reloaded: {summary}", set=json.dumps(changes))
        return self._reply_doc("reload", rid, "ok", f"reloaded: {summary}", result={"reloads": self.reloads})


def _peek_id(payload: bytes) -> Any:
    """The id of a request that could not be taken, when it can still be read (for the reply)."""
    try:
        doc = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None
    return doc.get("id") if isinstance(doc, dict) else None
