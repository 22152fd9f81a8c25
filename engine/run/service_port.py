"""A service a stage serves: its queryable, its pump thread, the requests' decoding, the refusals
and the replies.

The service is a zenoh queryable on ``vgr/<run>/<stage>/srv/<service>`` (engine.transport.bus.service_key)
whose callback only appends each query to an unbounded queue (engine.transport.bus.Inbox: zenoh's threads
never wait for Python). The service's pump thread (:meth:`ServicePort.pump`) takes the queries in
arrival order and, for each one:

* with ``security:``, a request from a session that is not a process the recipe wires to the
  service (a stage of it ``uses`` the service, or it is this stage's own process), or that does not
  say who it is, is refused: a warning ``caller_refused`` naming the session, and an error reply
  (which process a session is: engine.transport.peers, checked against the links by
  engine.transport.link_identity). Without it, anyone who reaches the run is its own user (private
  sockets; tools such as plugins/sim/cell_controller.py drive the simulated devices so) or came over
  an endpoint the recipe left unauthenticated: the request is served and recorded with its caller;
* a STOP envelope sent as a request is refused, never acted on (no query of a run carries STOP): a
  warning ``stop_refused`` naming the caller, and an error reply;
* a request that cannot be decoded, or is not of the service's request type, gets an error reply;
* a request whose caller stopped waiting while it queued is not served (a warning
  ``request_expired``, engine.transport.bus.overdue_ms): doing it now would help no one;
* any other is handed to the stage by the runtime's serve function (engine.run.runtime: under the
  stage's lock, with its counters), answered with the reply or the error, and the run's observers
  are told who called (:class:`~engine.run.stage_host.ServedCall`: the caller's process and zenoh session).

The pump ends when the run stops or the runtime wakes it (:meth:`ServicePort.wake`). The port sees
its runtime only as its :class:`~engine.run.stage_host.PortOwner`; what a request means is the stage's
business.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from engine.messages import Message, codec
from engine.messages.codec import CodecError, Kind
from engine.run.stage_host import ServedCall
from engine.transport.bus import StopMarker, overdue_ms
from engine.transport.peers import sender_zid

if TYPE_CHECKING:
    from engine.run.stage_host import PortOwner
    from engine.transport.bus import Inbox

# hands a request to the stage: (service, reply type, request) -> ((payload, envelope) or None, error)
Serve = Callable[[str, type[Message], Message], tuple[tuple[bytes, bytes] | None, str]]
_STOP = Kind.STOP  # (an Enum attribute lookup costs more than the test)


class ServicePort:
    """Service *svc* of stage runtime *rt*, its queries arriving in *queryable*; *serve* hands each
    request to the stage and returns the encoded reply (or None) and the error (empty when none)."""

    def __init__(self, rt: PortOwner, svc: str, queryable: Inbox, serve: Serve) -> None:
        self.rt = rt
        self.svc = svc
        self.queryable = queryable
        self.serve = serve
        graph = rt.host.graph
        # the processes that may call: those of the stages that use this service, and this stage's own
        self.callers = frozenset(
            {rt.node.spec.process}
            | {
                graph.nodes[e.client].spec.process
                for e in graph.service_edges
                if e.provider == rt.name and e.service == svc
            }
        )

    def wake(self) -> None:
        """End the pump (the run is stopping): a marker it takes as its cue, after what is queued."""
        self.queryable.wake()

    def pump(self) -> None:
        """Thread body: take the service's queries in order and answer each one (see the module
        docstring) until the run stops."""
        rt, svc = self.rt, self.svc
        stop = rt.host.stop_event
        spec = rt.node.cls.services[svc]
        secured = rt.host.secured
        while True:
            arrived_ns, query = self.queryable.recv_timed()
            with query:
                if stop.is_set():
                    return
                if isinstance(query, StopMarker):  # the runtime's own wake-up (see wake())
                    return
                att = query.attachment
                caller_zid = sender_zid(query)
                caller = rt.host.process_of(caller_zid)
                try:
                    env = codec.decode_envelope(att.to_bytes() if att is not None else b"")
                    if env.kind == _STOP:  # no zenoh query of a run carries STOP: refused, never acted on
                        self._refuse_stop(caller_zid, query)
                        continue
                    if secured and caller not in self.callers:
                        self._refuse_caller(caller, caller_zid, query)
                        continue
                    payload = query.payload.to_bytes() if query.payload is not None else b""
                    request = codec.decode(payload, env)
                    if not isinstance(request, spec.request):
                        raise CodecError(f"service {svc!r} takes {spec.request.TYPE}, got {type(request).__name__}")
                except CodecError as exc:
                    query.reply_err(f"bad request to {rt.name}.{svc}: {exc}")
                    continue
                late_ms = overdue_ms(query, arrived_ns)
                if late_ms is not None:  # its caller gave up while it queued: doing it now helps no one
                    why = f"not served: its caller stopped waiting {late_ms:.0f} ms before this stage was free"
                    rt.event("warning", "request_expired", f"{svc}: request {request.seq} {why}", service=svc)
                    query.reply_err(f"{rt.name}.{svc}: {why}")
                    continue
                reply_bytes, error = self.serve(svc, spec.reply, request)
                self._served(caller, caller_zid, request, error)
                if reply_bytes is not None:
                    query.reply(query.key_expr, reply_bytes[0], attachment=reply_bytes[1])
                else:
                    query.reply_err(f"{rt.name}.{svc} failed: {error}")

    def _refuse_caller(self, caller: str | None, caller_zid: str | None, query: Any) -> None:
        rt, svc = self.rt, self.svc
        who = f"process {caller!r}" if caller else f"zenoh session {caller_zid}" if caller_zid else "an unnamed session"
        msg = (
            f"{svc}: refused a request from {who}: the recipe wires this service to "
            f"{', '.join(sorted(self.callers))} only"
        )
        rt.event("warning", "caller_refused", msg, service=svc, caller_zid=caller_zid or "")
        query.reply_err(f"{rt.name}.{svc}: not a caller of this service")

    def _refuse_stop(self, caller_zid: str | None, query: Any) -> None:
        rt, svc = self.rt, self.svc
        who = rt.host.process_of(caller_zid) or f"zenoh session {caller_zid or 'unknown'}"
        msg = f"{svc}: refused a STOP envelope sent as a request by {who}"
        rt.event("warning", "stop_refused", msg, service=svc, caller_zid=caller_zid or "")
        query.reply_err(f"{rt.name}.{svc}: a STOP envelope is not a request")

    def _served(self, caller: str | None, caller_zid: str | None, request: Message, error: str) -> None:
        """Tell the observers (the recorder) who called: the caller's process and session."""
        observers = self.rt.host.observers
        if observers:
            served = ServedCall(
                self.rt.name, self.svc, caller or "", caller_zid or "", request.TYPE, request.seq, error
            )
            for obs in observers:
                obs.on_served(served)
