"""One output port of a stage at run time: where its messages go, its sequence counter and its lock.

Consumers in this process are offer functions of their input queues (``local``, see
engine.run.runtime.StageRuntime._offerer). Consumers in other vgr processes get the port's messages
through ``wire`` (engine.transport.wire.WireSender, over the unix-socket link of a consumer of this
host that asked for one before the port's first message, :meth:`OutputPort.attach_link` and
engine.transport.local_link, else on the internal key ``vgr/<run>/_wire/<stage>/<port>``;
large payloads as read-only views of the port's own pool when every consumer process is on this
host, engine.transport.shm_views, else from the bus's zenoh shared-memory pool, engine.transport.shm);
the public key ``vgr/<run>/<stage>/<port>`` is put to, one message per sample, only while a foreign
subscriber (a robot controller, a viewer) listens there — zenoh's matching status says when. The
publish path itself is the stage runtime's (engine.run.runtime.StageRuntime.publish); the port sees that
runtime only as its :class:`~engine.run.stage_host.PortOwner`.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

import zenoh

from engine.messages import codec
from engine.transport.bus import data_key, wire_key
from engine.transport.local_link import LinkSender
from engine.transport.shm_views import VIEW_MIN_BYTES, ViewPool, consumer_order
from engine.transport.wire import WireSender

if TYPE_CHECKING:
    from engine.run.stage_host import PortOwner


def _joined(head: bytes, bulk: Any) -> bytes:
    return b"".join((head, bulk))


class OutputPort:
    """Output *port* of stage runtime *rt*: its zenoh publishers, local consumers, sequence counter
    and lock (seq order == delivery order == wire order)."""

    def __init__(self, rt: PortOwner, port: str) -> None:
        self.port = port
        self.type = rt.node.cls.all_outputs()[port]
        self.format = codec.DataFormat(self.type.TYPE)  # envelope of this port's messages, packed in one call
        self.lock = threading.Lock()
        self.seq = 0
        self.closed = False
        self.local: list[Any] = []  # offer functions of the consumers' inputs in this process
        host = rt.host
        graph = host.graph
        here = rt.node.spec.process
        remote = [
            (graph.nodes[e.dst].spec.process, e.dst, e.dst_port)
            for e in graph.consumers_of(rt.name, port)
            if graph.nodes[e.dst].spec.process != here
        ]
        self.remote_consumers = bool(remote)
        self._remote = frozenset(remote)  # (process, stage, input) of each consumer in another process
        self._linked: set[tuple[str, str, str]] = set()  # ... of those linked (engine.transport.local_link)
        self.publisher = host.bus.remote_publisher(data_key(host.run_id, rt.name, port))
        self.put = self.publisher.put
        shm = getattr(host.bus, "shm", None)  # large payloads through shared memory (engine.transport.shm)
        self.views = None  # ... or as views of this port's own pool (engine.transport.shm_views)
        if remote and shm is not None:
            self.views = ViewPool(host.bus.host_peers(host.run_id, here), consumer_order(remote))
            host.bus.view_pools.append(self.views)
        self.wire = (
            WireSender(
                host.bus.remote_publisher(wire_key(host.run_id, rt.name, port)), f"{rt.name}.{port}", shm, self.views
            )
            if self.remote_consumers
            else None
        )
        self.send = self.wire.send if self.wire is not None else None
        # the encoded message's two parts written straight into shared memory, when the wire is the
        # only taker of its bytes (see _update)
        self._wrap_parts = self._parts_into_shared_memory(shm) if shm is not None and self.wire is not None else None
        self._name = f"{rt.name}.{port}"
        self.wrap_parts = None
        self.external = bool(self.publisher.matching_status.matching)
        self.observed = bool(host.observers)  # observers are fixed before a run starts
        self._update()
        # (run on zenoh's own thread: it only sets two flags. A plain function would get a Python
        # thread of its own from zenoh-python, two per stage with its events port)
        self._listener = self.publisher.declare_matching_listener(
            zenoh.handlers.Callback(self._on_matching, indirect=False)
        )

    def attach_link(self, consumer: tuple[str, str, str], sock: Any) -> bool:
        """Take the link of *consumer* ((process, stage, input), one the graph names in another
        process): the port's messages go to it over *sock* from now on. Only before the port's first
        message, so none of them went to it through zenoh (engine.transport.local_link)."""
        with self.lock:
            if self.seq or self.closed or self.wire is None or consumer not in self._remote or consumer in self._linked:
                return False
            self._linked.add(consumer)
            link = LinkSender(sock, f"{self._name} -> {consumer[1]}.{consumer[2]}")
            self.wire.add_link(link, zenoh_too=len(self._linked) < len(self._remote))
            if self._wrap_parts is not None:  # views still, but never a zenoh buffer: a link takes bytes
                self._wrap_parts = self._parts_into_shared_memory(None)
            self._update()
            return True

    def _parts_into_shared_memory(self, shm: Any) -> Any:
        """``wrap_parts(head, bulk)``: into a block of the port's pool of views when its consumers
        can map it, else into a zenoh shared-memory buffer (engine.transport.shm.ShmPool.wrap_parts;
        *shm* None: joined bytes instead)."""
        place = self.views.place if self.views is not None else None
        zenoh_parts = shm.wrap_parts if shm is not None else _joined
        small = min(VIEW_MIN_BYTES, shm.min_bytes) if shm is not None else VIEW_MIN_BYTES  # below the pools' thresholds

        def wrap_parts(head: bytes, bulk: Any) -> Any:
            if len(head) + len(bulk) < small:  # (the common case: joined here, no further call)
                return b"".join((head, bulk))
            if place is not None:
                placed = place(head, bulk)
                if placed is not None:
                    return placed
            return zenoh_parts(head, bulk)

        return wrap_parts

    def _on_matching(self, status: Any) -> None:
        self.external = bool(status.matching)
        self._update()

    def _update(self) -> None:
        # something outside the process listens, or an observer records: the message must be encoded
        self.needs_bytes = self.remote_consumers or self.external or self.observed
        self.wrap_parts = None if self.external or self.observed else self._wrap_parts
