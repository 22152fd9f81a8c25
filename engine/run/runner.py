"""Running a recipe's stages in this process, from start-up barrier to clean shutdown: the
process's lifetime, the end of its run, its stop and its shutdown.

What the process is to the rest of the run (its tokens, the start-up barriers, the other processes
lost or finished, run control messages, who owns a service) is its :class:`~engine.run.membership.Membership`,
which the runner calls at the steps marked *membership* below; what a run comes to (its summary,
outcome, exit code, or RunError) is in engine.run.summary. Each stage runs in a
:class:`~engine.run.runtime.StageRuntime`, which sees the runner only as its
:class:`~engine.run.stage_host.StageHost`.

Life of a run (per process):

1. open the bus, construct this process's stages, declare publishers, input channels, services;
2. *membership*: declare liveliness tokens and, when the recipe spans several processes, wait
   until every stage of the recipe is declared (so no message is published before its consumer
   listens);
3. ``setup()`` each stage, start the remote inputs' and services' pump threads (a local input's
   starts when a message first waits for it); when the recipe spans several processes, wait (a
   while at most, *membership*) until every process got this far, so sources do not stream into a
   process still setting up; then start the source threads;
4. wait until every *driven* stage (sources and everything downstream of them) has finished here
   (found incrementally, see :meth:`Runner._settle`) and no other process still has active stages
   (*membership*); service-only stages then end their streams;
5. on a stage failure (``on_error: stop``), Ctrl-C or a stop from another process (*membership*):
   stop everything promptly (below);
6. ``teardown()`` every stage, undeclare (*membership*), close the zenoh session, return a
   :class:`~engine.run.summary.RunSummary`.

A stop, in order. :meth:`Runner.stop` (any thread, the SIGINT handler's included) only flags the run
and cancels its calls token: from then on ``ctx.call`` sends nothing (no robot move leaves any stage,
from a stage's own threads or from helper threads it started), and every call still waiting for its
reply returns at once with ``RunStoppingError`` (the zenoh query is abandoned, see engine.transport.bus). The
runner's thread then, first of all, ``halt()``s every device stage (motion stops), wakes every pump
and waits ``STOP_GRACE_S`` (2 s) for the stages' threads; a stage still busy after that (a handler
in a computation that does not look at ``ctx.stopping``) is reported once, as a ``stage_stuck``
warning, and left behind (its threads are daemons; what it does after the bus closed goes nowhere).
Each step is a run event that observers see (:meth:`Observer.on_run_event`; the recorder writes them
on ``/_vgr/run``): ``stop`` with the reason, ``halted`` per device, ``stage_stopped`` per stage that
was still running, ``stage_stuck``, and ``stop_done`` with the time from the stop to the last stage's
end (also :attr:`RunSummary.stop_to_end_s`).
"""

from __future__ import annotations

import collections
import contextlib
import gc
import logging
import tempfile
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from engine.clock import Clock, make_clock
from engine.graph import Graph
from engine.messages import Event
from engine.recipe.model import NAME_RE
from engine.run.local_links import link_inputs, listen_for_links
from engine.run.membership import Membership
from engine.run.process_memory import keep_freed_memory
from engine.run.runtime import StageRuntime, StageStats
from engine.run.stage_host import MessageObserver

# (defined in engine.run.summary; the engine and its users import them from here as well)
from engine.run.summary import RunError, RunSummary
from engine.stage import Stage
from engine.transport import discovery
from engine.transport.bus import Bus, CancelToken
from engine.transport.local_link import LinkListener, links_allowed
from engine.transport.session_config import plan_session

__all__ = ["Observer", "RunError", "RunSummary", "Runner", "recipe_dir"]

log = logging.getLogger("vgr.runner")

STOP_GRACE_S = 2.0  # after a stop, how long the stages' threads have to end before they are reported
SERVICE_EVENTS_KEPT = 1000  # events a held-open run (a cell service) keeps for its summary
DRAIN_TIMEOUT_S = 10.0  # at the normal end, how long consumers have to drain what service-only stages sent


class Observer(MessageObserver):
    """Sees a process's run: its start, every message of its stages (see MessageObserver), its end."""

    def on_start(self, runner: Runner) -> None:
        """The stages exist and are declared; nothing has run yet."""

    def on_run_event(self, ev: Event) -> None:
        """The run's own events, not a stage's: the runner's account of a stop (``stop``, ``halted``,
        ``stage_stopped``, ``stage_stuck``, ``stop_done``; see the module docstring) and what its
        membership saw of the other processes (``peer_lost``, ``control_refused``, ...; engine.run.membership).
        Called from any thread, the SIGINT handler's and zenoh's included: only enqueue here."""

    def on_finish(self, runner: Runner, summary: RunSummary) -> None:
        """The run is over (sessions closed); *summary* may be annotated (artifacts)."""


def recipe_dir(graph: Graph) -> Path:
    """The recipe's folder (relative paths of its ``security:`` block start there)."""
    path = graph.loaded.path
    return path.resolve().parent if path is not None else Path.cwd()


@contextlib.contextmanager
def _no_cyclic_gc() -> Iterator[None]:
    """The cyclic collector paused while the run is built: what is made then (the stages, their
    ports and queues) lives as long as the run, and each full pass walks all of it, so passes
    triggered by its own allocations made the start quadratic in the stages (1000 stages: 147 ms
    of 374 ms in the collector). Reference counting frees what it always does."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _driven_stages(graph: Graph) -> set[str]:
    """Sources and every stage reachable from a source through data edges."""
    driven = {n for n, node in graph.nodes.items() if node.cls.is_source()}
    for name in graph.order:
        if any(e.src in driven for e in graph.inputs_of(name)):
            driven.add(name)
    return driven


class Runner:
    """Runs the stages of one process of a recipe graph."""

    def __init__(
        self,
        graph: Graph,
        *,
        process: str = "main",
        run_id: str | None = None,
        clock: Clock | None = None,
        observers: list[Observer] | None = None,
        ready_timeout_s: float = 15.0,
        bus: Bus | None = None,
        freeze_gc: bool = False,
        run_dir: Path | None = None,
        certs_dir: str | None = None,
        hold_open: bool = False,
    ) -> None:
        recipe = graph.recipe
        if process not in graph.processes():
            raise RunError(
                f"recipe {recipe.name!r} has no stage in process {process!r} "
                f"(processes: {', '.join(graph.processes())})"
            )
        self.graph = graph
        self.process = process
        self.run_id = run_id or recipe.run_id or recipe.name
        if not NAME_RE.match(self.run_id):  # it is a chunk of every zenoh key: '**' would name every run
            raise RunError(
                f"run id {self.run_id!r}: use letters, digits, '_' and '-', starting with a letter (max 64); "
                "it becomes part of every key of the run, so wildcards such as '*' are refused"
            )
        # the run's folder (engine.run_folder): stages write their files there; None: a temporary
        # folder, removed at the end (a run made as a library call keeps no files unless asked)
        self.run_dir = run_dir
        self.seed = recipe.seed
        self.clock = clock or make_clock(recipe.clock)
        self.observers = list(observers or [])
        self.freeze_gc = freeze_gc
        self.stop_event = threading.Event()
        self.calls_token = CancelToken()  # cancelled by stop(): the stages' calls end (engine.transport.bus)
        self._stopped_at: float | None = None  # time.monotonic() of the stop
        self._stop_claim = threading.Lock()  # taken by the one stop() that stops the run
        self.stop_to_end_s: float | None = None
        self.started = False  # True once every local stage's setup() has run
        self.ready = threading.Event()  # set once every local stage runs (sources started): a service may serve
        # a cell service (engine.run.cell) holds its run open until release(): the end of the data
        # ends nothing, since each job comes as a request
        self.hold_open = hold_open
        self._released = threading.Event()
        self.before_shutdown: list[Any] = []  # called first in the shutdown, the bus still open (a service's close)
        self.stop_reason: str | None = None
        self.failed_stages: list[str] = []
        self.driven = _driven_stages(graph)
        self._own_bus = bus is None
        self._bus = bus
        self._links: LinkListener | None = None  # where this process's ports take links (engine.run.local_links)
        # endpoints, TLS and access control of this process's session, refused here (before any
        # file or session exists) when the recipe's settings cannot make it
        self.session = (
            None
            if bus is not None
            else plan_session(graph, process, self.run_id, base=recipe_dir(graph), certs_dir=certs_dir)
        )
        self.runtimes: dict[str, StageRuntime] = {}
        # a service runs for months: it keeps its last events only (the run log and the recordings keep all)
        self.events: list[Event] | collections.deque[Event] = (
            collections.deque(maxlen=SERVICE_EVENTS_KEPT) if hold_open else []
        )
        self._events_lock = threading.Lock()
        self._progress = threading.Event()
        self.started_at = datetime.now(UTC)
        # this process in the run: tokens, barriers, peers, control messages, who owns what
        plan = self.session
        self.secured = plan is not None and plan.secured
        self.members = Membership(
            graph,
            process,
            self.run_id,
            ready_timeout_s,
            self,
            bus,
            secured=self.secured,
            dialled=plan.dialled if plan is not None else None,
        )
        # end-of-run detection, incremental: the driven stages of this process not yet settled, and
        # for each, its inputs fed by driven stages (see _settle); done_checks counts the evaluations
        self._open_driven: set[str] = set()
        self._driven_ports: dict[str, dict[str, frozenset[str]]] = {}  # port -> the driven stages feeding it
        self._consumers: dict[str, set[str]] = {}  # driven stage -> the driven stages of this process it feeds
        self._open_lock = threading.Lock()
        self.done_checks = 0

    @property
    def bus(self) -> Bus:
        assert self._bus is not None, "bus not open"
        return self._bus

    # -- callbacks from runtimes -------------------------------------------------------------
    def note_event(self, ev: Event) -> None:
        if ev.level in ("result", "warning", "error", "alarm"):
            with self._events_lock:
                self.events.append(ev)
            level = {"result": logging.INFO, "warning": logging.WARNING}.get(ev.level, logging.ERROR)
            logging.getLogger(f"vgr.stage.{ev.stage}").log(level, "[%s] %s", ev.code, ev.message)

    def run_event(self, level: str, code: str, stage: str, message: str, **details: Any) -> None:
        """An event of the run's own, not a stage's (the stop and its steps; the membership's, such as
        ``peer_lost`` or ``control_refused``): the summary's events, the observers."""
        ev = Event(level=level, code=code, stage=stage, message=message, details=details)
        ev.stamp_ns = self.clock.now_ns()
        self.note_event(ev)
        for obs in self.observers:
            try:
                obs.on_run_event(ev)
            except Exception:
                log.exception("observer %r failed on a run event", obs)

    def stage_done(self, stage: str) -> None:
        self._settle(stage)

    def input_ended(self, stage: str) -> None:
        self._settle(stage)

    def _settle(self, stage: str) -> None:
        """Re-evaluate one driven stage of this process (a change came from it): it is settled when
        it has handled all its data, or when every input still open comes from a stage nothing drives
        (a device's truth stream, say: it ends only when the run ends, so it must not hold the run
        open) or from a stage of this process settled so (a solver fed by the camera's images, whose
        result feeds an evaluator: the images end when the run's data ends, and so then does the
        solver). A stage newly settled re-evaluates its consumers (a work list, not recursion: a chain
        of a thousand stages settles in one call). O(its ports) per change: the run's end is never
        found by walking the whole graph."""
        todo = [stage]
        while todo:
            settled = self._settle_one(todo.pop())
            if settled is not None:
                todo.extend(self._consumers.get(settled, ()))

    def _settle_one(self, stage: str) -> str | None:
        """:meth:`_settle` for one stage: *stage* when it is newly settled, else None."""
        rt = self.runtimes.get(stage)
        if rt is None or stage not in self._driven_ports:
            return None
        self.done_checks += 1
        driven_ports = self._driven_ports[stage]
        with self._open_lock:
            if stage not in self._open_driven:
                return None
            pending = set(rt.pending_inputs)  # (a copy: the stage's threads change it)
            live = [
                port
                for port in pending
                if any(src in self._open_driven or src not in self.runtimes for src in driven_ports.get(port, ()))
            ]
            settled = rt.data_done.is_set() or (bool(pending) and not live)
            if settled:
                self._open_driven.discard(stage)
        self._progress.set()
        return stage if settled else None

    # -- who is who (the membership answers; engine.run.stage_host.StageHost) --------------------
    def service_owner(self, stage: str) -> str | None:
        return self.members.service_owner(stage)

    def process_of(self, zid: str | None) -> str | None:
        return self.members.process_of(zid)

    def stage_failed(self, stage: str) -> None:
        rt = self.runtimes[stage]
        self.failed_stages.append(stage)
        if self.graph.recipe.on_error == "stop":
            self.stop(f"stage {stage!r} failed: {rt.stats.error}")
        else:
            rt.close_outputs()
            rt.data_done.set()
            self._settle(stage)

    def stop(self, reason: str, *, broadcast: bool = True) -> None:
        """Stop the run (idempotent). Other processes of the run are told unless *broadcast* is False."""
        # (a lock taken once and kept, without waiting: a stop from a stage's thread and one from the
        # SIGINT handler at the same time make one stop, and the handler never blocks the main thread)
        if self.stop_event.is_set() or not self._stop_claim.acquire(blocking=False):
            return
        self.stop_reason = reason
        self._stopped_at = time.monotonic()
        # the stop event first: it is recorded before anything the stop causes (the halts, ...)
        self.run_event("info", "stop", "", f"stopping: {reason}", reason=reason, process=self.process)
        self.stop_event.set()  # nothing new is sent: ctx.call checks it before a request leaves...
        self.calls_token.cancel()  # ...and the calls waiting for their replies return now
        self._progress.set()
        log.warning("stopping run %s: %s", self.run_id, reason)
        # stop() may run on a stage's own thread (a failure) or in the SIGINT handler: it only flags;
        # the main thread halts the devices and wakes the readers in _shutdown, so nothing here can
        # block on a full channel.
        if broadcast:
            self.members.broadcast_stop(reason)

    def release(self) -> None:
        """End a run held open (``hold_open``) in order, as if its data had ended: no stop, no halt."""
        self._released.set()
        self._progress.set()

    def _wake_all(self) -> None:
        """Unblock every pump thread of this process (non-blocking)."""
        for rt in self.runtimes.values():
            rt.wake()

    # -- the run -----------------------------------------------------------------------------
    def run(self) -> RunSummary:
        """Run to completion (or stop) and return the summary; RunError if the run cannot start."""
        t0 = time.monotonic()
        log.info("run %s of recipe %s, process %s: starting", self.run_id, self.graph.recipe.name, self.process)
        with contextlib.ExitStack() as scratch:
            if self.run_dir is None:  # stages write as in any run; what they write is not kept
                self.run_dir = Path(scratch.enter_context(tempfile.TemporaryDirectory(prefix="vgr-run-")))
            try:
                try:
                    with _no_cyclic_gc():
                        self._start()
                    self._wait_until_done()
                except KeyboardInterrupt:
                    self.stop("interrupted (Ctrl-C)")
                except RunError:
                    if not self.stop_event.is_set():
                        raise
                    # a stop (Ctrl-C, SIGTERM) while waiting at the start-up barrier: the stop is what
                    # happened (outcome interrupted, exit 130), not a run that could not start
            finally:
                self._shutdown()
        ok = not self.failed_stages and self.stop_reason is None and self.members.lost_peer is None
        summary = RunSummary(
            self.run_id,
            self.graph.recipe.name,
            self.process,
            ok,
            self.stop_reason or self.members.lost_peer,
            [rt.stats for rt in self.runtimes.values()],
            time.monotonic() - t0,
            list(self.events),
            stop_to_end_s=self.stop_to_end_s,
            shared_memory=self._shared_memory_counts(),
        )
        for obs in self.observers:
            obs.on_finish(self, summary)
        log.info("run %s ended: %s in %.2f s", self.run_id, summary.outcome, summary.wall_s)
        return summary

    def _shared_memory_counts(self) -> dict[str, int]:
        pool = getattr(self._bus, "shm", None)
        if pool is None:
            return {}
        # payloads that went through shared memory: as views of a port's pool (engine.transport.shm_views)
        # or through zenoh's; fallbacks: large payloads sent as bytes
        views = sum(v.shared for v in getattr(self._bus, "view_pools", ()))
        return {"payloads": pool.shared + views, "fallbacks": pool.fallbacks}

    def _start(self) -> None:
        if self._bus is None:
            assert self.session is not None
            self._bus = self.members.bus = Bus(self.session.settings, self.session.extra)
        local = self.graph.stages_in(self.process)
        for name in local:
            self.runtimes[name] = StageRuntime(self, self.graph.nodes[name])
        self._track_driven()
        for obs in self.observers:
            obs.on_start(self)
        for name, rt in self.runtimes.items():
            node = self.graph.nodes[name]
            try:
                rt.stage = node.cls(rt, node.params)
            except Exception as exc:
                raise RunError(
                    f"stage {name!r} ({node.cls.type_name}) could not be created: {type(exc).__name__}: {exc}"
                ) from exc
            rt.declare_outputs()
        topics = discovery.graph_topics(self.graph, self.run_id, self.process)
        discovery.announce(self.bus, self.run_id, self.process, topics)  # what `vgr topics` and foreign tools read
        links = self._own_bus and links_allowed(self.graph.recipe.zenoh_for(self.process), self.secured)
        if links:  # (before joining: a process of this host that has joined has its listener)
            self._links = listen_for_links(self.run_id, self.process, self.runtimes)
        for rt in self.runtimes.values():
            rt.declare_inputs(self.runtimes)
        self.members.join(local, drives=bool(self.driven & self.runtimes.keys()) or self.hold_open)
        self.members.await_stages()
        if links:  # every process has joined: the producers of this host listen, and none has started
            link_inputs(self.runtimes)
        for name in local:
            rt = self.runtimes[name]
            rt.stats.state = "running"
            try:
                assert rt.stage is not None
                rt.stage.setup()
            except Exception as exc:
                rt.fail(exc, "setup")
        if self.stop_event.is_set():
            return
        if self.freeze_gc:
            # what exists now (modules, stage state from setup) lives as long as the process: keep it
            # out of the cyclic collector, whose full passes over a heap with numpy, scipy and
            # Open3D loaded otherwise pause every thread for tens of milliseconds now and then
            gc.collect()
            gc.freeze()
            keep_freed_memory()  # large messages' buffers reused, not mapped anew (engine.run.process_memory)
        self.started = True
        for name in local:
            rt = self.runtimes[name]
            if name not in self.driven and not rt.node.cls.inputs:
                rt.data_done.set()  # pure service providers do not hold the run open
            rt.start_threads()
        self.members.await_started()
        for name in local:
            self.runtimes[name].start_source()
        self.ready.set()

    def _track_driven(self) -> None:
        """Before the stages start: every driven stage of this process is open until :meth:`_settle`."""
        for name in self.runtimes:
            if name in self.driven:
                ports: dict[str, set[str]] = {}
                for e in self.graph.inputs_of(name):
                    if e.src in self.driven:
                        ports.setdefault(e.dst_port, set()).add(e.src)
                        if e.src in self.runtimes:
                            self._consumers.setdefault(e.src, set()).add(name)
                self._driven_ports[name] = {port: frozenset(srcs) for port, srcs in ports.items()}
                self._open_driven.add(name)

    def _wait_until_done(self) -> None:
        for name in list(self._driven_ports):  # (whatever ended before this loop began)
            self._settle(name)
        while not self.stop_event.is_set():
            if self.hold_open and not self._released.is_set():
                pass  # (a cell service: until release())
            elif not self._open_driven and self.members.ended_everywhere():
                break
            self._progress.wait(0.05)
            self._progress.clear()
        if self.stop_event.is_set():
            return
        # the data is complete everywhere: service-only stages end their streams, consumers drain
        self._halt_busy_devices()
        for name in self.graph.stages_in(self.process):
            rt = self.runtimes[name]
            if name not in self.driven and not rt.node.cls.inputs:
                rt.close_outputs()
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        # (the stages not done yet, checked from the first one still open: every wake costs O(1) but
        # for the stages that ended since; all of them at every wake was O(stages^2) for a fan-out)
        left, first = list(self.runtimes.values()), 0
        while True:
            while first < len(left) and left[first].data_done.is_set():
                first += 1
            if first == len(left) or self.stop_event.is_set() or time.monotonic() > deadline:
                break
            self._progress.wait(0.05)
            self._progress.clear()

    def _shutdown(self) -> None:
        if self._bus is None:
            return
        for before in self.before_shutdown:
            try:
                before()
            except Exception:
                log.exception("closing %r failed", before)
        self.stop_event.set()  # ends service pumps and idle readers; a failure only if stop_reason is set
        if self.stop_reason:
            self._halt_devices()  # motion stops first
        if self._links is not None:
            self._links.close()
        self._wake_all()
        self._join_stages()
        for name in reversed(self.graph.stages_in(self.process)):
            self.runtimes[name].teardown()
        self.members.leave()
        if self._own_bus:
            self._bus.close()

    def _join_stages(self) -> None:
        """Wait for the stages' threads (``STOP_GRACE_S`` in all); after a stop, say which stages it
        ended, by when, and which one did not end (once per stage, a warning: the stop is what
        happened, and its thread's stack would not say more than its name)."""
        deadline = time.monotonic() + STOP_GRACE_S
        stopped = self.stop_reason is not None
        running = {name for name, rt in self.runtimes.items() if rt.stats.state == "running"}
        for rt in self.runtimes.values():
            for t in list(rt.threads):  # (a local input's pump may start late: see StageRuntime.start_threads)
                t.join(max(0.0, deadline - time.monotonic()))
        ended_by = 0.0  # seconds from the stop to the end of the last stage that ended
        stuck_stages: list[str] = []
        for name, rt in self.runtimes.items():
            was_running = name in running
            if was_running:
                rt.stats.state = "stopped" if stopped else "finished"
            stuck = [t.name for t in rt.threads if t.is_alive()]
            after_s = max(0.0, rt.threads_ended_at - (self._stopped_at or 0.0))
            if stuck:
                stuck_stages.append(rt.name)
                rt.stats.error = rt.stats.error or (
                    f"still busy {STOP_GRACE_S:g} s after the stop ({', '.join(stuck)}): left behind"
                )
                self.run_event("warning", "stage_stuck", rt.name, rt.stats.error, threads=stuck)
            elif stopped and was_running:
                ended_by = max(ended_by, after_s)
                self.run_event(
                    "info", "stage_stopped", rt.name, f"stopped {after_s:.3f} s after the stop", after_s=after_s
                )
        if stopped and self._stopped_at is not None:
            self.stop_to_end_s = time.monotonic() - self._stopped_at if stuck_stages else ended_by
            if stuck_stages:
                msg = f"stage(s) {', '.join(stuck_stages)} did not end within {STOP_GRACE_S:g} s of the stop"
            else:
                msg = f"every stage ended within {ended_by:.3f} s of the stop"
            self.run_event("info", "stop_done", "", msg, after_s=self.stop_to_end_s, stuck=stuck_stages)

    def _halt_devices(self) -> None:
        """Motion stops first: every stage that drives a device halts it before anything else ends."""
        for name, rt in self.runtimes.items():
            self._halt(name, rt, str(self.stop_reason))

    def _halt_busy_devices(self) -> None:
        """The data is complete, yet a device stage is still serving a request whose caller stopped
        waiting (a move that timed out, its alarm raised): the device is halted as a stop would halt
        it, and its handler given ``STOP_GRACE_S`` to return before its streams end."""
        for name, rt in self.runtimes.items():
            service = rt.serving
            halted = service and self._halt(name, rt, f"the run's data ended while it still served {service!r}")
            if halted and rt.lock.acquire(timeout=STOP_GRACE_S):
                rt.lock.release()

    def _halt(self, name: str, rt: StageRuntime, reason: str) -> bool:
        """Halt *rt*'s device if its stage drives one (True), with a ``halted`` or ``halt_failed`` event."""
        stage = rt.stage
        if stage is None or type(stage).halt is Stage.halt:
            return False
        try:
            stage.halt()
        except Exception as exc:  # the others must still be halted
            log.error("halting %s failed: %s: %s", name, type(exc).__name__, exc)
            log.debug("halting %s failed", name, exc_info=True)  # (its traceback, with -vv)
            self.run_event("error", "halt_failed", name, f"{type(exc).__name__}: {exc}")
        else:
            self.run_event("warning", "halted", name, f"halted: {reason}")
        return True

    def snapshot(self) -> list[StageStats]:
        """Live per-stage counters (for progress displays)."""
        return [rt.stats for rt in self.runtimes.values()]
