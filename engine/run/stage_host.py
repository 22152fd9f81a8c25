"""The interfaces between a run's owner, a stage's runtime and the stage's ports: what a
:class:`~engine.run.runtime.StageRuntime` needs of the runner of its process (:class:`StageHost`; the
runner owns the bus, the stages' lifetime and the run's end), what a stage's ports need of their
runtime (:class:`PortOwner`), and what both tell a run observer (:class:`MessageObserver`). Each side
depends on these, never on the other's module: the engine's imports have no circle
(tests/engine_core/test_import_graph.py)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import threading
    from pathlib import Path

    from engine.clock import Clock
    from engine.graph import Graph, ServiceEdge, StageNode
    from engine.messages import Event, Message
    from engine.messages.codec import Envelope
    from engine.transport.bus import Bus, CancelToken

Deliver = Callable[[Any], None]  # hands one message of an input port (or its END) to the stage


@dataclass(frozen=True, slots=True)
class ServiceCall:
    """A completed service call: *stage* called ``edge.provider.edge.service`` through *client*."""

    stage: str
    client: str
    edge: ServiceEdge
    req_payload: bytes
    req_env: bytes
    reply_payload: bytes  # empty (and reply_env too) when no reply came
    reply_env: bytes
    error: str  # why the call failed; empty when it was answered
    elapsed_s: float = 0.0  # from the request leaving to the reply (a figure for people, never recorded)


@dataclass(frozen=True, slots=True)
class ServedCall:
    """A request *stage* served on its *service*, and who sent it: the caller's process (empty when
    the calling session is not one of the run's) and zenoh session (empty when the query did not say)."""

    stage: str
    service: str
    caller_process: str
    caller_zid: str
    request_type: str
    request_seq: int
    error: str  # why it was not answered; empty when it was


class MessageObserver:
    """Sees every message the stages of a process publish, receive, handle and exchange, in order.

    Calls come from stage threads; an observer must be quick and thread-safe.
    """

    def on_publish(self, stage: str, port: str, payload: bytes, envelope: bytes, msg: Message) -> None:
        """*stage* published *msg* on *port* (encoded: payload + envelope)."""

    def on_receive(self, src_stage: str, src_port: str, payload: bytes, envelope: bytes) -> None:
        """A message of a stage in another process arrived here (before it is delivered)."""

    def on_deliver(self, stage: str, port: str, env: Envelope) -> None:
        """*stage* is about to handle message ``env.seq`` of its input *port*."""

    def on_stage_finish(self, stage: str) -> None:
        """All inputs of *stage* have ended; its ``finish()`` is about to run."""

    def on_service(self, call: ServiceCall) -> None:
        """A stage's service call is complete (answered or failed)."""

    def on_served(self, call: ServedCall) -> None:
        """A stage has served a request (answered or failed), from the caller named in *call*."""


class StageHost(Protocol):
    """What a stage's runtime uses of the runner of its process."""

    graph: Graph
    run_id: str
    run_dir: Path | None  # the run's folder (engine.run_folder), None when there is none
    seed: int
    clock: Clock
    stop_event: threading.Event  # set once the run stops
    calls_token: CancelToken  # cancelled once the run stops: its stages' calls end at once
    started: bool  # every stage of the process has been set up
    secured: bool  # the recipe has `security:`: a service serves only the processes wired to it

    @property
    def bus(self) -> Bus: ...

    @property
    def observers(self) -> Sequence[MessageObserver]: ...  # fixed before the run starts

    # what a stage's runtime tells its host: an event for the run's summary; that *stage* has handled
    # all its data (its outputs have ended); that it failed (its error is in its stats), upon which
    # the host stops the run or goes on, as the recipe says
    def note_event(self, ev: Event) -> None: ...

    # who is who: the ZenohId that owns *stage* (its replies are the only ones taken), and the run's
    # process that a ZenohId is (None: not one of the run's)
    def service_owner(self, stage: str) -> str | None: ...
    def process_of(self, zid: str | None) -> str | None: ...
    def stage_done(self, stage: str) -> None: ...
    def input_ended(self, stage: str) -> None: ...  # one input of *stage* ended (others still open)
    def stage_failed(self, stage: str) -> None: ...


class PortOwner(Protocol):
    """What a port (engine.run.output_port, engine.run.remote_input, engine.run.service_port) uses of its stage's
    runtime."""

    name: str
    node: StageNode
    host: StageHost

    @property
    def lock(self) -> AbstractContextManager[Any]: ...  # held while the stage handles a message

    def event(self, level: str, code: str, message: str, **details: Any) -> None: ...

    def spawn_thread(self, name: str, target: Any, *args: Any) -> None: ...  # one of the stage's threads
