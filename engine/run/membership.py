"""This process's membership of its run: the liveliness tokens it declares, the start-up barriers
it waits at, the other processes it watches (lost or finished, restarted), the run-wide control
messages it sends and takes, and who owns which service.

The runner (engine.run.runner) keeps the process's lifetime, its stop and its shutdown; it goes through
its :class:`Membership` at fixed points of the run (engine.run.runner's module docstring, steps 2 to 4
and 6):

* :meth:`Membership.join` — declare this process: in a multi-process run its ``_peer`` token (its
  zenoh session and epoch, engine.transport.peers), the ``_control`` subscriber and its ``_active`` token when
  it drives stages; in every run a ``_ready/<stage>`` token per stage (keys: engine.transport.bus);
* :meth:`Membership.await_stages` — wait until every stage of the recipe is declared, in whichever
  process (RunError after ``ready_timeout_s``), then say with which members this process starts: a
  process that finds the others started with another epoch of it (it was restarted mid-run) raises
  the alarm ``rejoin_refused`` and stops, unless the recipe says ``rejoin: true``;
* :meth:`Membership.await_started` — every process has set up its stages before sources start (a
  slower one is warned about, not waited for);
* :meth:`Membership.ended_everywhere` — this process's driven stages are done (its ``_active``
  token goes): has every other process finished too?
* :meth:`Membership.broadcast_stop` — tell the other processes the run stops;
* :meth:`Membership.leave` — its ``stopped`` marker if the run stopped (the broadcast again, in a
  form that is not lost as the session closes), its ``done`` marker, then every token removed
  (engine.transport.peers: a process whose token vanishes without ``done`` crashed).

A peer whose token vanishes without ``done`` is an alarm ``peer_lost`` and stops the run (with
``rejoin: true``: a warning, and the alarm only when it has not rejoined within ``ready_timeout_s``);
:attr:`Membership.lost_peer` then says why, and the run failed even if it was ending anyway.
A ``_control`` message from a session that is not one of the run's other processes is refused
(warning ``control_refused``); this process's own, delivered back to it, is ignored.

The membership sees its runner only as a :class:`RunControl` (the stop, its flag and reason, the
run's events) and never imports engine.run.runner: the engine's imports have no circle
(tests/engine_core/test_import_graph.py). A single-process run has no peers: only its ``_ready``
tokens are declared, and every service is its own.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from functools import partial
from typing import Any, Protocol

import zenoh

from engine.graph import Graph
from engine.run.summary import RunError
from engine.transport.bus import Bus, LiveSet, active_key, control_key, ready_key, started_key
from engine.transport.link_identity import ACCEPT, LinkIdentity, Verdict, link_facts, session_links
from engine.transport.peers import PeerWatch, members_digest, new_epoch, peer_key, peer_process, sender_zid

# the runner's log: what the membership logs is part of the runner's account of the run
log = logging.getLogger("vgr.runner")
# how long the end-of-run check waits for the peer watch to see how a departed process left (its
# ``done`` comes before its tokens go, on the same subscriber, so this is a wait for a queued callback)
LEFT_WAIT_S = 2.0


class RunControl(Protocol):
    """What the membership uses of its process's runner."""

    stop_event: threading.Event  # set once the run stops
    stop_reason: str | None

    def stop(self, reason: str, *, broadcast: bool = True) -> None: ...

    # an event of the run's own (not a stage's): the summary's events, the observers (the recording)
    def run_event(self, level: str, code: str, stage: str, message: str, **details: Any) -> None: ...


class Membership:
    """One process's membership of the run *run_id* of *graph* (see the module docstring)."""

    def __init__(
        self,
        graph: Graph,
        process: str,
        run_id: str,
        ready_timeout_s: float,
        run: RunControl,
        bus: Bus | None,
        *,
        secured: bool = False,
        dialled: dict[str, str] | None = None,
    ) -> None:
        self.graph = graph
        self.secured = secured  # the run has `security:`: sessions are known by their certificates
        self.dialled = dialled or {}  # endpoint this process connects to -> the process there
        self.process = process
        self.run_id = run_id
        self.ready_timeout_s = ready_timeout_s
        self.run = run
        self.bus = bus  # set by the runner once it has opened its bus
        self.multi_process = len(graph.processes()) > 1
        self.epoch = new_epoch()  # this start of this process (engine.transport.peers)
        self.peers: PeerWatch | None = None  # the run's processes (multi-process runs)
        self._active: LiveSet | None = None  # other processes' _active tokens (multi-process runs)
        self._tokens: dict[str, Any] = {}  # declared in this order, undeclared in it by leave()
        self._peer_key = ""
        self.lost_peer: str | None = None  # why a peer process was lost (crashed, lease lost): the run failed
        self._lost: set[tuple[str, str]] = set()  # (process, zid) already reported lost
        self._lost_lock = threading.Lock()
        self.links: LinkIdentity | None = None  # who is who by this session's links (multi-process runs)
        self._impostors: set[str] = set()  # zenoh sessions already named as impostors

    def _bus(self) -> Bus:
        assert self.bus is not None, "bus not open"
        return self.bus

    # -- who is who (engine.transport.peers) ---------------------------------------------------------------
    def service_owner(self, stage: str) -> str | None:
        """The ZenohId that owns *stage* (its replies are the only ones taken)."""
        process = self.graph.nodes[stage].spec.process
        if process == self.process or self.peers is None:
            return self._bus().zid
        return self.peers.owner(process)

    def process_of(self, zid: str | None) -> str | None:
        """The run's process that the session *zid* is (None: not one of the run's)."""
        if zid is not None and self.bus is not None and zid == self.bus.zid:
            return self.process
        return self.peers.process_of(zid) if self.peers is not None else None

    # -- joining the run -------------------------------------------------------------------------
    def join(self, stages: list[str], drives: bool) -> None:
        """Declare this process (multi-process runs) and its *stages*; *drives*: some of them are
        driven (sources and what they feed), so the run is not over while they are active."""
        bus = self._bus()
        if self.multi_process:
            self._join_peers()
            bus.subscribe(control_key(self.run_id), self._on_control)
            if drives:
                self._tokens["active"] = bus.token(active_key(self.run_id, self.process))
            self._active = bus.watch_alive(active_key(self.run_id, "*"))
        for name in stages:
            self._tokens[name] = bus.token(ready_key(self.run_id, name))

    def _join_peers(self) -> None:
        """Watch the run's processes and declare this one (its session and epoch), before its stages'
        ready tokens: whoever sees a stage ready has its owner's token already (engine.transport.peers)."""
        bus = self._bus()
        self.links = LinkIdentity(
            partial(session_links, bus.session), self.process, secured=self.secured, dialled=self.dialled
        )
        peers = self.peers = PeerWatch(
            self.run_id,
            self.graph.recipe.rejoin,
            on_lost=self._peer_lost,
            on_stopped=self._peer_stopped,
            on_restart=self._peer_restarted,
            verify=self._verify_claim,
            on_refused=self._impostor,
            own=(self.process, bus.zid),
        )
        if self.secured:  # a second session with a certificate of the run is seen as its link comes up
            self._tokens["links"] = bus.session.info.declare_link_events_listener(
                zenoh.handlers.Callback(self._on_link, indirect=True), history=True
            )
        peers.start(bus)
        self._peer_key = peer_key(self.run_id, self.process, bus.zid, self.epoch)
        self._tokens["peer"] = bus.token(self._peer_key)

    def await_stages(self) -> None:
        """Multi-process runs: every stage declared, then the members this process starts with."""
        if self.multi_process:
            self._barrier()
            self._check_epochs()

    def await_started(self) -> None:
        """Multi-process runs: every process set up before the sources start (see _start_barrier)."""
        if self.multi_process:
            self._start_barrier()

    def _check_epochs(self) -> None:
        """Say with which members this process starts; a process that finds the others started with
        another epoch of it (it was restarted mid-run) is refused unless the recipe says ``rejoin: true``."""
        assert self.peers is not None
        procs = set(self.graph.processes())
        missing = self.peers.wait_for(procs, self.ready_timeout_s, stop=self.run.stop_event)
        if missing and self.run.stop_event.is_set():
            raise RunError(f"run stopped while waiting for the processes: {self.run.stop_reason}")
        if missing:
            raise RunError(self._unconfirmed(missing))
        digest = members_digest({**self.peers.epochs(), self.process: self.epoch})
        self._tokens["peer_started"] = self._bus().token(f"{self._peer_key}/started/{digest}")
        self.peers.wait_for(procs - {self.process}, self.ready_timeout_s, "started")
        under_way = self.peers.restarted_under_way(self.process, self.epoch)
        if under_way and not self.graph.recipe.rejoin:
            msg = (
                f"process {self.process!r} (epoch {self.epoch}) joins run {self.run_id} already under way "
                f"(process(es) {', '.join(under_way)} started with another epoch of it): refused; "
                "the recipe's `rejoin: true` allows it"
            )
            self.run.run_event("alarm", "rejoin_refused", "", msg, process=self.process, epoch=self.epoch)
            self.run.stop(msg, broadcast=False)
        elif under_way:
            self.run.run_event(
                "warning",
                "rejoined",
                "",
                f"process {self.process!r} rejoins run {self.run_id} (epoch {self.epoch})",
                process=self.process,
                epoch=self.epoch,
            )

    def _start_barrier(self) -> None:
        """Every process has set up its stages and reads its inputs: only then do sources start, so
        the first messages do not pile up in a process still setting up (they would not be lost,
        only late). A process slower than ``ready_timeout_s`` is warned about, not waited for."""
        self._tokens["started"] = self._bus().token(started_key(self.run_id, self.process))
        missing = self._wait_alive(partial(started_key, self.run_id), set(self.graph.processes()))
        if missing and not self.run.stop_event.is_set():
            log.warning(
                "starting the sources although process(es) %s not set up after %g s",
                ", ".join(sorted(missing)),
                self.ready_timeout_s,
            )

    def _barrier(self) -> None:
        """Wait until every stage of the recipe is declared, in whichever process."""
        missing = self._wait_alive(partial(ready_key, self.run_id), set(self.graph.nodes))
        if missing and self.run.stop_event.is_set():
            raise RunError(f"run stopped while waiting for stages: {self.run.stop_reason}")
        if missing:
            where = ", ".join(f"{m} (process {self.graph.nodes[m].spec.process})" for m in sorted(missing))
            raise RunError(
                f"after {self.ready_timeout_s:g} s these stages are not running: {where}. "
                f"Start `vgr run RECIPE --process NAME` for each process, with the same run id "
                f"({self.run_id}) and zenoh endpoints that connect them."
            )

    def _wait_alive(self, key: Callable[[str], str], names: set[str]) -> set[str]:
        """Wait until the liveliness token ``key(name)`` of each of *names* is up, the run stops, or
        ``ready_timeout_s`` has passed; returns the names still missing. A liveliness subscriber
        reports each token as it appears, so every process goes on as soon as the last one is up
        (no polling delay between the processes' starts)."""
        deadline = time.monotonic() + self.ready_timeout_s
        live = self._bus().watch_alive(key("*"))
        try:
            while True:
                keys, version = live.snapshot()
                missing = {n for n in names if key(n) not in keys}
                left = deadline - time.monotonic()
                if not missing or left <= 0 or self.run.stop_event.is_set():
                    return missing
                live.wait(version, min(left, 0.5))  # (0.5 s: notice a stop without a token change)
        finally:
            live.close()

    # -- who may claim to be whom (engine.transport.link_identity) ------------------------------------
    def _verify_claim(self, process: str, zid: str) -> Verdict:
        """Is session *zid* the run's *process*? (This process's own name comes only from its own
        session: the peer watch ignores the others.)"""
        if process == self.process or self.links is None:
            return ACCEPT
        return self.links.verdict(process, zid)

    def _unconfirmed(self, missing: set[str]) -> str:
        """Why *missing* processes are not members after the wait: no claim, or one the links never confirmed."""
        assert self.peers is not None
        held = self.peers.held()
        why = []
        for process in sorted(missing):
            ends = [e for e, p in self.dialled.items() if p == process]
            if process in held and ends:
                why.append(
                    f"process {process} is claimed by zenoh session {', '.join(held[process])}, but nothing "
                    f"answers on its endpoint {ends[0]}: not taken for it (engine.transport.link_identity)"
                )
            else:
                why.append(f"process {process} did not say who it is (engine.transport.peers)")
        return "; ".join(why) + f" after {self.ready_timeout_s:g} s"

    def _on_link(self, event: Any) -> None:
        """A link came or went (``security:`` runs): a certificate of the run held by two sessions
        is a copied key, and the run stops."""
        if self.links is None or self.bus is None:
            return
        # (the link the event brings is checked with the others: the session's list may not show it yet)
        link = getattr(event, "link", None)
        new = [] if link is None or event.kind != zenoh.SampleKind.PUT else [link_facts(link)]
        shared = self.links.shared_certificates(self.graph.processes(), self.bus.zid, also=new)
        for process, zids in sorted(shared.items()):
            taken = self.bus.zid if process == self.process else self.peers.owner(process) if self.peers else None
            others = ", ".join(sorted(zids - {taken}))
            self._impostor(process, others, f"sessions {', '.join(sorted(zids))} hold its certificate")

    def _impostor(self, process: str, zid: str, why: str) -> None:
        """A session claims a process of the run that this session's links say it is not: an alarm,
        and the run stops (motion first): someone else may answer as that process."""
        with self._lost_lock:
            if zid in self._impostors:
                return
            self._impostors.add(zid)
        code = "identity_shared" if self.secured else "peer_impostor"
        msg = f"refused zenoh session {zid} as process {process!r}: {why}"
        self.run.run_event("alarm", code, "", msg, process=process, zid=zid)
        self.lost_peer = self.lost_peer or msg  # the run failed
        self.run.stop(msg)

    # -- during the run --------------------------------------------------------------------------
    def ended_everywhere(self) -> bool:
        """This process's driven stages have all settled: its ``_active`` token goes (once). True
        when no other process still has active stages either (always, in a single-process run)."""
        token = self._tokens.pop("active", None)
        if token is not None:
            token.undeclare()
        if self._active is None:
            return True
        own = active_key(self.run_id, self.process)
        if self._active.snapshot()[0] - {own}:
            return False
        return self._others_left_in_order()

    def _others_left_in_order(self) -> bool:
        """No other process has active stages: True when each is still a member or left in order
        (its ``done``). A process whose session lost its lease or crashed loses its ``_active`` and
        ``_peer`` tokens at once, and their two watchers may be told in either order: seen from here,
        its stages would have "ended". So the ``_peer`` tokens alive now are asked for (a liveliness
        query), and one gone without ``done`` is lost (an alarm; the run fails) before this process
        may end as if the data were complete."""
        if self.peers is None or self.bus is None:
            return True
        alive = {peer_process(key) for key in self.bus.alive(peer_key(self.run_id, "*", "*", "*"))}
        for process in self.graph.processes():
            if process == self.process or process in alive:
                continue
            left = self.peers.left_in_order(process, LEFT_WAIT_S)
            if not left:
                self._peer_lost(process, self.peers.last_zid(process) or "?")
                return False
        return True

    def _peer_lost(self, process: str, zid: str) -> None:
        """A process's token vanished without its ``done`` marker: it crashed or lost its lease.
        Said once per session of the process (the peer watch and the end-of-run check may both see it)."""
        if self.run.stop_event.is_set() or process == self.process:
            return
        with self._lost_lock:
            if (process, zid) in self._lost:
                return
            self._lost.add((process, zid))
        if self.graph.recipe.rejoin:
            self.run.run_event(
                "warning",
                "peer_lost",
                "",
                f"process {process!r} (zenoh session {zid}) "
                f"vanished; waiting {self.ready_timeout_s:g} s for it to rejoin",
                process=process,
            )
            timer = threading.Timer(self.ready_timeout_s, self._rejoin_overdue, (process,))
            timer.daemon = True
            timer.start()
            return
        msg = f"process {process!r} (zenoh session {zid}) vanished without finishing: crashed or lost its lease"
        self.run.run_event("alarm", "peer_lost", "", msg, process=process, zid=zid)
        self.lost_peer = self.lost_peer or msg  # the run failed, even when it was ending anyway
        self.run.stop(msg)

    def _rejoin_overdue(self, process: str) -> None:
        if self.peers is not None and self.peers.owner(process) is None and not self.run.stop_event.is_set():
            msg = f"process {process!r} vanished and did not rejoin within {self.ready_timeout_s:g} s"
            self.run.run_event("alarm", "peer_lost", "", msg, process=process)
            self.lost_peer = self.lost_peer or msg
            self.run.stop(msg)

    def _peer_restarted(self, process: str, old: str, new: str, accepted: bool) -> None:
        if accepted:
            self.run.run_event(
                "warning",
                "peer_rejoined",
                "",
                f"process {process!r} rejoined: epoch {old} -> {new}",
                process=process,
                epoch=new,
            )
        else:
            self.run.run_event(
                "warning",
                "rejoin_refused",
                "",
                f"process {process!r} started again (epoch {new}, "
                f"the run's is {old}): refused, its replies and control messages are not taken "
                "(the recipe's `rejoin: true` allows it)",
                process=process,
                epoch=new,
            )

    # -- run control (vgr/<run>/_control) --------------------------------------------------------
    def broadcast_stop(self, reason: str) -> None:
        """Tell the run's other processes that it stops (multi-process runs, while the bus is open)."""
        bus = self.bus
        if not self.multi_process or bus is None or bus.closed:
            return
        try:
            bus.put(control_key(self.run_id), json.dumps({"stop": reason, "process": self.process}).encode())
        except Exception:
            log.exception("could not broadcast the stop")

    def _peer_stopped(self, process: str) -> None:
        """*process* says, as it leaves, that its run stopped: this one stops too (its broadcast,
        which says why, may have been lost as its session closed)."""
        if process != self.process:
            self.run.stop(f"stopped by process {process!r}", broadcast=False)

    def _on_control(self, sample: Any) -> None:
        zid = sender_zid(sample)
        if zid is not None and self.bus is not None and zid == self.bus.zid:
            return  # this process's own message (its own stop, already acted on), delivered back to it
        # (a stop said just before its sender left may arrive after the removal of its token)
        sender = self.peers.process_of(zid, gone=True) if self.peers is not None else None
        try:
            msg = json.loads(sample.payload.to_bytes())
            said = msg.get("process") if isinstance(msg, dict) else None
        except ValueError:
            msg, said = None, None
        if sender is None or sender == self.process or said != sender:  # not one of the run's processes
            who = f"zenoh session {zid}" if zid else "a session that did not say who it is"
            self.run.run_event(
                "warning",
                "control_refused",
                "",
                f"refused a _control message from {who} (claims {said!r}): not one of the run's processes",
                zid=zid or "",
                claimed=str(said),
            )
            return
        if "stop" in msg:
            self.run.stop(f"stopped by process {sender!r}: {msg['stop']}", broadcast=False)

    # -- leaving ---------------------------------------------------------------------------------
    def leave(self) -> None:
        """End in order: the ``done`` marker is said before the tokens go (engine.transport.peers), then every
        token is removed, in the order it was declared."""
        if self.peers is not None:
            with contextlib.suppress(Exception):
                if self.run.stop_reason is not None:  # (what the broadcast said, in a form not lost)
                    self._tokens["peer_stopped"] = self._bus().token(f"{self._peer_key}/stopped")
                self._tokens["peer_done"] = self._bus().token(f"{self._peer_key}/done")
            self.peers.close()
        if self._active is not None:
            self._active.close()
        for tok in self._tokens.values():
            with contextlib.suppress(Exception):
                tok.undeclare()
        self._tokens.clear()
