"""Deterministic replay of a recording: re-run stages on recorded inputs, diff every output.

Which stages re-run: by default every stage of the recorded process except sources and stages whose
role is sensor or device (cameras, trackers, robots): those are fed from the file. ``stages=``
chooses explicitly (any non-source stage).

How: one thread, no zenoh, a simulated clock. The records are walked in file order — the order the
live run's stages actually handled their inputs (``/_vgr/deliveries``), not arrival order. Before
each record the clock is set to its recorded time; the replay never reads the wall clock (``speed``
only throttles how fast records are fed, for watching). A re-run stage's service call is answered
by the recorded reply of the same client's k-th call (and the request it sends is compared with the
recorded one) unless the provider re-runs too, in which case the provider answers. Each stage gets
the same seed-derived random generator as in the run. Outputs are then compared with engine.recording.diff.

A replay's outputs may become the new golden recording (``vgr replay --update``): engine.recording.replay_update
writes it.
"""

from __future__ import annotations

import logging
import tempfile
import time
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine.clock import SimClock
from engine.graph import Graph, StageNode, build_graph
from engine.messages import Event, Message, canonical, codec, freeze
from engine.plugin_manager import Registry, load_registry
from engine.recipe.model import load_recipe
from engine.recording.diff import DIFFERENT, StreamVerdict, compare_stream
from engine.recording.reader import Exchange, RecordedMessage, Recording, load
from engine.stage import EVENTS_PORT, PLAYBACK_ROLES, ServiceError, ServiceTimeoutError, StageContext
from engine.transport.bus import topic_of

log = logging.getLogger("vgr.replay")
ViewSink = Callable[[str, str, bytes, int], None]  # (topic, vgr type, payload, log time ns): a live view


class ReplayError(RuntimeError):
    """The recording cannot be replayed as asked (unknown stage, recipe mismatch, ...)."""


@dataclass
class Output:
    seq: int
    stamp_ns: int
    type_name: str
    payload: bytes
    msg: Message


@dataclass
class ReplayReport:
    recording: str
    rerun: list[str]
    streams: list[StreamVerdict]
    requests: list[StreamVerdict]
    failures: list[str] = field(default_factory=list)
    outputs: dict[str, list[Output]] = field(default_factory=dict)
    requests_sent: dict[tuple[str, str], list[tuple[int, bytes]]] = field(default_factory=dict)
    alarms: list[str] = field(default_factory=list)  # "<stage>: [code] message" of the replayed run

    @property
    def ok(self) -> bool:
        return all(v.verdict != DIFFERENT for v in (*self.streams, *self.requests))

    @property
    def outcome(self) -> str:
        """The replay's outcome (its exit code by engine.exit_codes): ``failed`` when a stage failed,
        ``different`` when an output differs from the recording, else ``ok``: every output came back,
        alarms included (a refused job replays as refused, and that is a pass: :attr:`alarms` and the
        report's ``recorded_outcome`` say so)."""
        if self.failures:
            return "failed"
        return "ok" if self.ok else "different"


class _ReplayContext(StageContext):
    def __init__(self, replayer: Replayer, node: StageNode) -> None:
        recipe_dir = replayer.rec.recipe_dir
        log = logging.getLogger(f"vgr.replay.{node.name}")
        super().__init__(node.name, replayer.run_id, replayer.graph.recipe.seed, replayer.clock, log, recipe_dir)
        self.run_dir = replayer.run_dir  # the replay's own folder: what a stage writes never lands in the run's
        self.replayer = replayer
        self.node = node
        self.seq: dict[str, int] = defaultdict(int)
        self.causal_stamp = 0
        self.failed = False

    @property
    def stopping(self) -> bool:
        return False

    def sleep(self, seconds: float) -> bool:
        self.clock.advance(seconds)
        return True

    def publish(self, port: str, msg: Message) -> None:
        outs = self.node.cls.all_outputs()
        if port not in outs:
            raise ValueError(f"stage {self.name!r} has no output port {port!r}")
        if not isinstance(msg, outs[port]):
            raise TypeError(f"stage {self.name!r}: port {port!r} carries {outs[port].TYPE}, got {type(msg).__name__}")
        stamp = msg.stamp_ns or self.causal_stamp or self.clock.now_ns()
        msg = freeze(msg)
        if msg.stamp_ns != stamp:
            msg.stamp_ns = stamp
        msg = canonical(msg)
        self.seq[port] += 1
        msg.seq = self.seq[port]
        out = Output(msg.seq, msg.stamp_ns, msg.TYPE, codec.encode_payload(msg), msg)
        topic = topic_of(self.name, port)
        self.replayer.outputs[topic].append(out)
        if self.replayer.view is not None:
            self.replayer.view(topic, msg.TYPE, out.payload, self.clock.now_ns())
        self.replayer.output_by_seq[(topic, msg.seq)] = out

    def call(self, client: str, request: Message, timeout_s: float = 10.0) -> Message:
        return self.replayer.serve_call(self, client, request)

    def has_client(self, client: str) -> bool:
        return any(e.client == self.name and e.client_name == client for e in self.replayer.graph.service_edges)

    def event(self, level: str, code: str, message: str, **details: Any) -> None:
        tb = details.pop("traceback", "")
        details = self.files_in_run(details)
        self.publish(
            EVENTS_PORT, Event(level=level, code=code, stage=self.name, message=message, traceback=tb, details=details)
        )


class Replayer:
    def __init__(
        self,
        rec: Recording,
        graph: Graph,
        rerun: list[str],
        speed: float | None = None,
        run_dir: Path | None = None,
        view: ViewSink | None = None,
    ) -> None:
        self.rec = rec
        self.view = view  # shown every played-back and re-run message (engine.recording.live_view)
        self.run_dir = run_dir
        self.graph = graph
        self.rerun = rerun
        self.speed = speed
        self.run_id = rec.metadata.get("vgr.run", {}).get("run_id", graph.recipe.name)
        self.clock = SimClock(int(rec.metadata.get("vgr.run", {}).get("clock_start_ns", SimClock.DEFAULT_EPOCH_NS)))
        self.outputs: dict[str, list[Output]] = defaultdict(list)
        self.output_by_seq: dict[tuple[str, int], Output] = {}  # (topic, seq) -> the re-run's output
        self.contexts: dict[str, _ReplayContext] = {}
        self.stages: dict[str, Any] = {}
        self.exchanges: dict[tuple[str, str], deque[Exchange]] = defaultdict(deque)
        self.requests_sent: dict[tuple[str, str], list[tuple[int, bytes]]] = defaultdict(list)
        self.provider_replies: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
        self.recorded_replies: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
        self.failures: list[str] = []
        # a recording that begins mid-run (a cell service's cycle file, engine.recording.cycle_files): the
        # sequence numbers of the re-run stages' outputs and calls go on from where the file begins
        self.call_seq_base: dict[tuple[str, str], int] = {}

    # -- service calls made by re-run stages ---------------------------------------------------
    def serve_call(self, ctx: _ReplayContext, client: str, request: Message) -> Message:
        edge = next((e for e in self.graph.service_edges if e.client == ctx.name and e.client_name == client), None)
        if edge is None:
            raise ServiceError(f"stage {ctx.name!r} has no service client {client!r}")
        if not request.stamp_ns:
            request.stamp_ns = ctx.causal_stamp or self.clock.now_ns()
        sent = self.requests_sent[(ctx.name, client)]
        request.seq = len(sent) + 1 + self.call_seq_base.get((ctx.name, client), 0)
        sent.append((request.seq, codec.encode_payload(request)))
        if edge.provider in self.stages:
            reply = self._provider_answer(edge.provider, edge.service, request)
            if isinstance(reply, str):
                raise ServiceError(f"{ctx.name} -> {edge.provider}.{edge.service}: {reply}")
            return reply
        queue = self.exchanges[(ctx.name, client)]
        if not queue:
            raise ServiceError(
                f"{ctx.name} -> {edge.provider}.{edge.service}: the recording has no reply for "
                f"call #{len(sent)} (the replayed stage calls more often than the recorded one)"
            )
        ex = queue.popleft()
        if ex.error:
            if "no reply" in ex.error or "within" in ex.error:
                raise ServiceTimeoutError(f"{ctx.name} -> {edge.provider}.{edge.service}: {ex.error}")
            raise ServiceError(f"{ctx.name} -> {edge.provider}.{edge.service}: {ex.error}")
        return codec.decode_payload(codec.registry.get(ex.reply_type), ex.reply)

    def _provider_answer(self, provider: str, service: str, request: Message) -> Message | str:
        ctx = self.contexts[provider]
        stage = self.stages[provider]
        ctx.causal_stamp = request.stamp_ns
        try:  # live, both travel as bytes: the provider and the caller see their wire forms
            reply = stage.on_request(service, canonical(request))
            if not reply.stamp_ns:
                reply.stamp_ns = request.stamp_ns or self.clock.now_ns()
            return canonical(reply)
        except Exception as exc:
            error = f"{type(exc).__name__}: {exc}"
            ctx.event("error", "service_exception", f"{service}: {error}")
            return error
        finally:
            ctx.causal_stamp = 0

    # -- the walk ------------------------------------------------------------------------------
    def _fail(self, ctx: _ReplayContext, exc: BaseException, where: str) -> None:
        import traceback

        ctx.failed = True
        text = f"{type(exc).__name__} in {where}: {exc}"
        self.failures.append(f"{ctx.name}: {text}")
        ctx.event("error", "stage_exception", text, traceback="".join(traceback.format_exception(exc)), where=where)

    def run(self) -> ReplayReport:
        """Re-run the stages over the recording; without a run folder, stages write their files in
        a temporary one, removed at the end (they must behave as in the recorded run)."""
        if self.run_dir is not None:
            return self._run()
        with tempfile.TemporaryDirectory(prefix="vgr-replay-") as scratch:
            self.run_dir = Path(scratch)
            try:
                return self._run()
            finally:
                self.run_dir = None

    def _run(self) -> ReplayReport:
        playback: dict[tuple[str, int], RecordedMessage] = {}
        recorded_out: dict[str, list[RecordedMessage]] = defaultdict(list)
        rerun = set(self.rerun)
        for r in self.rec.records:  # pre-pass: inputs by (topic, seq), recorded outputs, recorded exchanges
            if r[0] == "msg":
                m: RecordedMessage = r[1]
                if m.stage in rerun:
                    recorded_out[m.topic].append(m)
                else:
                    playback[(m.topic, m.seq)] = m
            elif r[0] == "svc" and r[1].caller in rerun:
                self.exchanges[(r[1].caller, r[1].client)].append(r[1])
                self.call_seq_base.setdefault((r[1].caller, r[1].client), r[1].request_seq - 1)
        for name in self.graph.order:
            if name in rerun:
                node = self.graph.nodes[name]
                ctx = _ReplayContext(self, node)
                for recorded in recorded_out.values():  # (a file that begins mid-run)
                    if recorded and recorded[0].stage == name:
                        ctx.seq[recorded[0].port] = recorded[0].seq - 1
                self.contexts[name] = ctx
                self.stages[name] = node.cls(ctx, node.params)
        for name, stage in self.stages.items():
            try:
                stage.setup()
            except Exception as exc:
                self._fail(self.contexts[name], exc, "setup")
        last_t: int | None = None
        for r in self.rec.records:
            t = r[-1] if r[0] in ("deliver", "finish") else (r[1].log_time if r[0] in ("svc", "msg") else None)
            if self.speed and t is not None and last_t is not None and t > last_t:
                time.sleep((t - last_t) / 1e9 / self.speed)  # throttling only; never read back
            last_t = t if t is not None else last_t
            if r[0] == "msg" and self.view is not None and r[1].stage not in rerun:
                self.view(r[1].topic, r[1].type_name, r[1].payload, r[1].log_time)
            if r[0] == "deliver":
                self._deliver(r, playback)
            elif r[0] == "finish" and r[1] in self.stages:
                ctx = self.contexts[r[1]]
                if not ctx.failed:
                    self.clock.advance_to(r[2])
                    try:
                        self.stages[r[1]].finish()
                    except Exception as exc:
                        self._fail(ctx, exc, "finish")
            elif r[0] == "svc" and r[1].provider in self.stages and r[1].caller not in rerun:
                self._answer_recorded_request(r[1])
        for name in reversed(list(self.stages)):
            try:
                self.stages[name].teardown()
            except Exception as exc:
                self.failures.append(f"{name}: teardown: {exc}")
        return self._report(recorded_out)

    def _deliver(self, r: tuple[Any, ...], playback: dict[tuple[str, int], RecordedMessage]) -> None:
        _, stage, port, src_topic, seq, t = r
        if stage not in self.stages:
            return
        ctx = self.contexts[stage]
        if ctx.failed:
            return
        src_stage = src_topic.split("/")[1]
        if src_stage in self.stages:
            out = self.output_by_seq.get((src_topic, seq))
            if out is None:
                self.failures.append(f"{stage}: input {src_topic}[seq {seq}] was recorded but not replayed")
                return
            msg = out.msg
        else:
            m = playback.get((src_topic, seq))
            if m is None:
                raise ReplayError(f"recording lacks {src_topic}[seq {seq}] delivered to {stage}.{port}")
            msg = codec.decode_payload(codec.registry.get(m.type_name), m.payload)
            msg.seq = seq
            if not msg.stamp_ns:
                msg.stamp_ns = m.publish_time
        self.clock.advance_to(t)
        ctx.causal_stamp = msg.stamp_ns
        try:
            self.stages[stage].on_message(port, msg)
        except Exception as exc:
            self._fail(ctx, exc, f"on_message({port!r})")
        finally:
            ctx.causal_stamp = 0

    def _answer_recorded_request(self, ex: Exchange) -> None:
        self.clock.advance_to(ex.log_time)
        request = codec.decode_payload(codec.registry.get(ex.request_type), ex.request)
        request.seq = ex.request_seq
        reply = self._provider_answer(ex.provider, ex.service, request)
        key = f"/{ex.provider}/srv/{ex.service} <- {ex.caller}.{ex.client}"
        got = reply.encode("utf-8") if isinstance(reply, str) else codec.encode_payload(reply)
        want = ex.error.encode("utf-8") if ex.error else ex.reply
        n = len(self.provider_replies[key]) + 1
        self.provider_replies[key].append((n, got))
        self.recorded_replies[key].append((n, want))

    def _report(self, recorded_out: dict[str, list[RecordedMessage]]) -> ReplayReport:
        streams = []
        topics = sorted(set(recorded_out) | set(self.outputs))
        for topic in topics:
            rec = recorded_out.get(topic, [])
            rep = self.outputs.get(topic, [])
            type_name = rec[0].type_name if rec else rep[0].type_name
            streams.append(
                compare_stream(topic, type_name, [(m.seq, m.payload) for m in rec], [(o.seq, o.payload) for o in rep])
            )
        requests = []
        for (caller, client), sent in sorted(self.requests_sent.items()):
            recorded = [(e.request_seq, e.request) for e in self._all_exchanges(caller, client)]
            if not recorded and not sent:
                continue
            edge = next(e for e in self.graph.service_edges if e.client == caller and e.client_name == client)
            if edge.provider in self.stages:
                continue  # answered by the re-run provider: its outputs are compared instead
            type_name = self.graph.nodes[caller].cls.uses[client].request.TYPE
            requests.append(compare_stream(f"/{caller}/_svc/{client} (requests)", type_name, recorded, sent))
        for key, got in sorted(self.provider_replies.items()):
            want = self.recorded_replies[key]
            v = StreamVerdict(f"{key} (replies)", len(want), len(got), "identical")
            diff = next((i for i, (a, b) in enumerate(zip(want, got, strict=True)) if a[1] != b[1]), None)
            if diff is not None:
                v.verdict, v.first_difference = DIFFERENT, f"reply #{diff + 1} differs"
            requests.append(v)
        return ReplayReport(
            str(self.rec.path),
            list(self.rerun),
            streams,
            requests,
            list(self.failures),
            dict(self.outputs),
            dict(self.requests_sent),
            self._alarms(),
        )

    def _alarms(self) -> list[str]:
        """Alarms of the replayed run: those the re-run stages raised now, the others' as recorded."""
        events: list[Any] = []
        for topic, outs in self.outputs.items():
            if topic.endswith(f"/{EVENTS_PORT}"):
                events += [o.msg for o in outs]
        for r in self.rec.records:
            if r[0] == "msg" and r[1].stage not in self.stages and r[1].topic.endswith(f"/{EVENTS_PORT}"):
                events.append(codec.decode_payload(Event, r[1].payload))
        return [f"{e.stage}: [{e.code}] {e.message}" for e in events if e.level == "alarm"]

    def _all_exchanges(self, caller: str, client: str) -> list[Exchange]:
        return [r[1] for r in self.rec.records if r[0] == "svc" and r[1].caller == caller and r[1].client == client]


def default_rerun(graph: Graph, process: str) -> list[str]:
    return [
        n
        for n in graph.order
        if graph.nodes[n].spec.process == process
        and not graph.nodes[n].cls.is_source()
        and graph.nodes[n].cls.role not in PLAYBACK_ROLES
    ]


def replay(
    path: str | Path,
    *,
    recipe: str | Path | None = None,
    overrides: list[str] | None = None,
    stages: list[str] | None = None,
    speed: float | None = None,
    registry: Registry | None = None,
    run_dir: Path | None = None,
    view: ViewSink | None = None,
) -> tuple[ReplayReport, Recording, Graph]:
    """Replay *path*; *recipe* replaces the recorded recipe (e.g. a changed solver parameter).
    Stages that write files write them in *run_dir* (the replay's folder), none without one; *view*
    sees every message (``vgr replay --view``)."""
    rec = load(path)
    if recipe is not None:
        loaded = load_recipe(recipe, overrides)
    else:
        loaded = load_recipe(
            f"{rec.path}#recipe",
            [*rec.overrides, *(overrides or [])],
            text=rec.recipe_text,
            base=rec.recipe_dir or rec.path.parent,
        )
    registry = registry or load_registry(loaded.recipe.plugins)
    graph = build_graph(loaded, registry)
    process = rec.metadata.get("vgr.run", {}).get("process", "main")
    if stages:
        unknown = [s for s in stages if s not in graph.nodes]
        if unknown:
            raise ReplayError(f"unknown stage(s) {', '.join(unknown)}; stages: {', '.join(graph.order)}")
        played = [s for s in stages if graph.nodes[s].cls.is_source() or graph.nodes[s].cls.role in PLAYBACK_ROLES]
        if played:  # re-running a device stage would connect to it and command it: replay never does
            raise ReplayError(
                f"{', '.join(played)}: sources, sensors and devices are always played back from the recording "
                "(replay never connects to or commands a device)"
            )
        rerun = [n for n in graph.order if n in stages]
    else:
        rerun = default_rerun(graph, process)
    report = Replayer(rec, graph, rerun, speed, run_dir, view).run()
    return report, rec, graph
