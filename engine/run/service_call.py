"""One service call's exchange on the bus: the request out, the owner's one answer back, decoded, and
the exchange told to the run's observers (the recorder) whatever its outcome.

Both callers of a run's services use it: a stage's runtime (engine.run.runtime ``StageRuntime.call``,
for the stage's declared clients) and the cell service (engine.run.cell.service, for the job of a
controller's request). What a failure means to each (a stage error, a cell status) is theirs; what
went over the wire, and how, is this module's.

The answer must come from the session that owns the provider stage, and only one may come
(engine.transport.peers.owners_answer): a reply from any other session is refused
(:class:`~engine.transport.peers.ForgedReply`, with the replying sessions in ``repliers``) and
nothing is taken from it, so nothing moves on it.
"""

from __future__ import annotations

from collections.abc import Iterable
from time import perf_counter

from engine.graph import ServiceEdge
from engine.messages import Message, codec
from engine.run.stage_host import MessageObserver, ServiceCall, StageHost
from engine.transport.bus import RequestCancelled, service_key
from engine.transport.peers import owners_answer

CUT_SHORT = "cut short: the run is stopping"


def exchange(
    host: StageHost,
    caller: str,
    edge: ServiceEdge,
    request: Message,
    timeout_s: float,
    observers: Iterable[MessageObserver],
) -> Message:
    """Send *request* (stamped and numbered by the caller) to ``edge.provider.edge.service`` and return
    the decoded reply, of whatever type it is (the caller checks it).

    Raises what the exchange raises: ``TimeoutError`` (no reply in *timeout_s*), ``LookupError``
    (nothing answered), ``RuntimeError`` (the service's error reply), ``ForgedReply``,
    ``RequestCancelled`` (the run stopped first), ``CodecError`` (a reply that does not decode).
    Every *observer* is told the exchange (:class:`~engine.run.stage_host.ServiceCall`) either way."""
    payload, att = codec.encode(request)
    reply_payload, reply_att, error = b"", b"", ""
    t0 = perf_counter()
    try:
        answers = host.bus.request(
            service_key(host.run_id, edge.provider, edge.service), payload, att, timeout_s, host.calls_token
        )
        where = f"{caller} -> {edge.provider}.{edge.service}"
        answer = owners_answer(answers, host.service_owner(edge.provider), where)
        if answer.error is not None:
            raise RuntimeError(answer.error)
        reply_payload, reply_att = answer.payload, answer.attachment
        return codec.decode(reply_payload, codec.decode_envelope(reply_att))
    except RequestCancelled:
        error = CUT_SHORT
        raise
    except Exception as exc:
        error = str(exc)
        raise
    finally:
        elapsed = perf_counter() - t0
        done = ServiceCall(caller, edge.client_name, edge, payload, att, reply_payload, reply_att, error, elapsed)
        for obs in observers:
            obs.on_service(done)
