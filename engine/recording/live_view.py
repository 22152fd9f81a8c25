"""The live view: every topic of a run (or a replay) served to the Foxglove app over WebSocket.

``vgr run --view [PORT]`` and ``vgr replay --view [PORT]`` start a Foxglove WebSocket server (the
``foxglove-sdk`` package; clients offering the protocol as ``foxglove.sdk.v1`` or by its older name
``foxglove.websocket.v1`` are both served, engine/recording/view_proxy.py) on ``127.0.0.1``
(``--view-host`` for another address) and serve each output stream as a channel named like its recording topic
(``/<stage>/<port>``), protobuf-encoded with the schema the recorder writes for it
(:func:`engine.messages.schemas.descriptor_set`: Foxglove schemas for geometry, ``vgr.v1`` for the rest), so the
app shows what it shows of a recording (docs/messages.md). In Foxglove: *Open connection*, *Foxglove
WebSocket*, ``ws://127.0.0.1:8765``; the layout ``docs/foxglove/vgr_layout.json`` applies.

The server only sends: it advertises no services, parameters or client publishing, so a viewer
cannot reach the run. Messages are logged with the run's clock as log time; a client slower than the
stream loses the oldest messages of its own queue (the SDK's backlog), never the run's.

Each channel keeps its last message and sends it again when a client subscribes (as a latched ROS
topic does), so a viewer that connects late, or to a robot pose published once, sees the current
state at once rather than at the next message. The server stops when the run (or the replay) ends;
``--view-hold`` keeps it up after that, with those last messages, until Ctrl-C: a run on the
simulated clock ends in about a second, before anyone could connect.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from engine.messages import codec
from engine.messages.schemas import descriptor_set
from engine.recording.view_proxy import ProtocolNameProxy
from engine.run.runner import Observer, Runner
from engine.transport.bus import topic_of
from engine.transport.discovery import graph_topics

if TYPE_CHECKING:
    from engine.messages import Message

log = logging.getLogger("vgr.live_view")
DEFAULT_PORT = 8765


class LiveView:
    """One Foxglove WebSocket server with a channel per topic (its own SDK context)."""

    def __init__(
        self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, name: str = "vgr", token: str | None = None
    ) -> None:
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._last: dict[str, tuple[bytes, int]] = {}  # topic -> its last message and log time
        self._lock = threading.Lock()
        try:  # the SDK's server on a loopback port of its own, the proxy where the user asked
            self.server = foxglove.start_server(
                name=name, host="127.0.0.1", port=0, context=self._context, server_listener=_latch(self)
            )
            self._proxy = ProtocolNameProxy(host, port, int(self.server.port), token)
        except Exception as exc:  # port taken, address not on this host
            with contextlib.suppress(Exception):
                self.server.stop()
            raise ValueError(f"cannot serve the live view on {host}:{port}: {exc}") from exc
        self.host = host
        self.port = self._proxy.port

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def channel(self, topic: str, schema: str) -> Any:
        """The channel of *topic* (made and advertised on first use)."""
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    fx = self._foxglove
                    ch = fx.Channel(
                        topic,
                        message_encoding="protobuf",
                        schema=fx.Schema(name=schema, encoding="protobuf", data=descriptor_set(schema)),
                        context=self._context,
                    )
                    self._channels[topic] = ch
        return ch

    def advertise_recording(self, path: str | Path) -> None:
        """Make the channels of the data topics of the recording *path* now (from its summary), so a
        client can subscribe before their first message. (foxglove-sdk 0.30 refused, as an unknown
        channel, a subscription that arrived just after a channel made at its first message.)"""
        from mcap.reader import make_reader

        try:
            with Path(path).open("rb") as f:
                summary = make_reader(f).get_summary()
        except Exception as exc:  # not a recording, cut short: the replay says so itself
            log.debug("no channels advertised from %s: %s", path, exc)
            return
        for ch in summary.channels.values() if summary is not None else ():
            type_name = ch.metadata.get("type", "")
            if type_name in codec.registry and not ch.topic.startswith("/_vgr/"):
                self.channel(ch.topic, codec.registry.get(type_name).SCHEMA)

    def log(self, topic: str, schema: str, payload: bytes | memoryview, log_time_ns: int) -> None:
        data = payload if type(payload) is bytes else bytes(payload)
        ch = self.channel(topic, schema)
        self._last[topic] = (data, log_time_ns)
        ch.log(data, log_time=log_time_ns)

    def resend_last(self, topic: str) -> bool:
        """Send *topic*'s last message again (to its subscribers); False when it has none yet."""
        last, ch = self._last.get(topic), self._channels.get(topic)
        if last is None or ch is None:
            return False
        ch.log(last[0], log_time=last[1])
        return True

    @property
    def topics_with_data(self) -> int:
        return len(self._last)

    def log_typed(self, topic: str, type_name: str, payload: bytes | memoryview, log_time_ns: int) -> None:
        """:meth:`log` for a message named by its vgr type (the schema is the type's)."""
        self.log(topic, codec.registry.get(type_name).SCHEMA, payload, log_time_ns)

    def close(self) -> None:
        self._proxy.close()
        try:
            self.server.stop()
        except Exception as exc:  # already stopped
            log.debug("live view stop: %s", exc)


def _latch(view: LiveView) -> Any:
    """The server listener of *view*: a client that subscribes gets the channel's last message (the
    SDK's other callbacks keep their do-nothing defaults). Made here, not at import: ``vgr`` imports
    this module for its options, and foxglove only when a view is asked for."""
    from foxglove.websocket import ChannelView, Client, ServerListener

    class Latch(ServerListener):
        def on_subscribe(self, client: Client, channel: ChannelView) -> None:
            view.resend_last(channel.topic)

    return Latch()


class ViewObserver(Observer):
    """Run observer feeding a :class:`LiveView`: the process's own outputs as they are published,
    and what arrives from stages of other processes."""

    def __init__(self, view: LiveView) -> None:
        self.view = view  # (its owner closes it: engine.cli.recording.end_view)
        self._runner: Runner | None = None
        self._last_remote: dict[str, int] = {}  # topic -> last seq shown (several local inputs may get one message)

    def on_start(self, runner: Runner) -> None:
        self._runner = runner
        for process in runner.graph.processes():  # advertised before data flows (see advertise_recording)
            for t in graph_topics(runner.graph, runner.run_id, process):
                self.view.channel(t.topic, t.schema)

    def _now(self) -> int:
        assert self._runner is not None
        return self._runner.clock.now_ns()

    def on_publish(self, stage: str, port: str, payload: bytes, envelope: bytes, msg: Message) -> None:
        self.view.log(topic_of(stage, port), msg.SCHEMA, payload, self._now())

    def on_receive(self, src_stage: str, src_port: str, payload: bytes, envelope: bytes) -> None:
        env = codec.decode_envelope(envelope)
        topic = topic_of(src_stage, src_port)
        if env.seq <= self._last_remote.get(topic, 0):
            return
        self._last_remote[topic] = env.seq
        self.view.log_typed(topic, env.type_name, payload, self._now())
