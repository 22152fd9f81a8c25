"""``vgr bag import BAG -o FILE.mcap``: a rosbag2 (MCAP or sqlite3 storage, CDR) as a vgr recording.

Each topic of a type vgr converts (plugins.ros2.convert: ``SUPPORTED``) becomes a vgr channel
``/<stage>/<port>``, its messages converted once (:func:`plugins.ros2.convert.decode`) and written
as a recorded run writes them (engine.recording.recorder): protobuf payload, ``log_time`` = the
bag's receive time, ``publish_time`` = the message's header stamp, ``sequence`` = 1, 2, ... per
channel. Topics of other types (or serialisations) and messages that do not convert are skipped,
each with a note naming the topic (and the field): the import goes on.

Which channel a ROS topic becomes, first rule that applies:

1. ``--topic /camera/depth/points=camera/cloud`` (repeatable);
2. with ``--recipe``: the output port of a ``ros2_subscribe`` stage of the recipe that subscribes
   to the topic (its ``topics: {port: {topic: ...}}``), i.e. what that stage would have published
   live; else the one output port of that vgr type of the recipe's played-back stages (sources,
   sensors, devices) that a stage reads;
3. the ROS topic's own name: ``/camera/points`` -> ``/camera/points`` (stage ``camera``, port
   ``points``); a one-level name goes under stage ``ros`` (``/joint_states`` -> ``/ros/joint_states``).

Replay walks a recording's deliveries (engine.recording.replay), so a recording that recipes replay
needs the recipe: with ``--recipe`` the file carries it (text, overrides, as a run records them)
and, for each message, a delivery to every stage that reads its port, then each re-run stage's
finish. ``vgr replay FILE.mcap`` then re-runs the recipe's stages on the bag's data (and ``--update``
makes their outputs the golden ones). Without ``--recipe`` the file holds the data only
(``vgr inspect``, ``vgr play``, Foxglove). A stage that calls a camera's or robot's *service*
(capture, move) cannot replay from a bag, which holds streams only: the summary says so.

FILE.mcap must not exist: it is created exclusively (engine.files.create_new: never through a link)
and removed again if the import fails.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from engine import __version__
from engine.files import create_new
from engine.messages import Message, codec
from engine.messages.schemas import descriptor_set, proto_class
from engine.recording.format import TOPIC_DELIVERIES, TOPIC_FINISH
from plugins.ros2.convert import SUPPORTED, ConversionError, decode
from plugins.ros2.convert_common import NothingConvertedError

DEFAULT_STAGE = "ros"  # the stage of one-level ROS topics (``/joint_states`` -> ``/ros/joint_states``)


class NothingToImportError(NothingConvertedError):
    """No topic of the bag converts: nothing is written (exit code 1); ``skipped`` says why."""


@dataclass
class ImportedTopic:
    ros_topic: str
    ros_type: str
    vgr_topic: str
    vgr_type: str
    messages: int = 0
    failed: int = 0
    fed: list[str] = field(default_factory=list)  # "stage.port" of every stage reading it (with --recipe)


@dataclass
class ImportReport:
    bag: str
    output: str
    storage: str
    recipe: str | None
    topics: list[ImportedTopic] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)  # {topic, type, reason}
    notes: list[str] = field(default_factory=list)
    deliveries: int = 0

    @property
    def messages_written(self) -> int:
        return sum(t.messages for t in self.topics)


def split_target(text: str) -> tuple[str, str]:
    """``stage/port`` (or ``/stage/port``, ``stage.port``) -> (stage, port)."""
    bare = text.strip("/")
    stage, sep, port = bare.partition("/") if "/" in bare else bare.partition(".")
    if not sep or not stage or not port:
        raise ValueError(f"--topic ...={text}: name a vgr stage and port, e.g. camera/cloud")
    return stage, port


def derived_target(ros_topic: str) -> tuple[str, str]:
    parts = [p for p in ros_topic.split("/") if p]
    if len(parts) >= 2:
        return parts[0], "/".join(parts[1:])
    return DEFAULT_STAGE, parts[0] if parts else "unnamed"


@dataclass
class RecipeTargets:
    """What a recipe's played-back stages publish: where bag topics go when no --topic says."""

    graph: Any
    played: list[str]
    subscribed: dict[str, tuple[str, str]]  # ROS topic -> (stage, port) of a ros2_subscribe-like stage

    @classmethod
    def of(cls, graph: Any) -> RecipeTargets:
        from engine.recording.replay import default_rerun

        rerun = set(default_rerun(graph, "main"))
        played = [n for n in graph.order if n not in rerun]
        subscribed: dict[str, tuple[str, str]] = {}
        for name in played:
            params = graph.nodes[name].params
            topics = getattr(params, "topics", None)
            if not isinstance(topics, dict):
                continue
            namespace = str(getattr(getattr(params, "ros", None), "namespace", "") or "").strip("/")
            for port, spec in topics.items():
                t = str(getattr(spec, "topic", ""))
                if t:
                    full = t if t.startswith("/") else f"/{namespace}/{t}" if namespace else f"/{t}"
                    subscribed.setdefault(full, (name, port))
        return cls(graph, played, subscribed)

    def port_type(self, stage: str, port: str) -> type[Message] | None:
        node = self.graph.nodes.get(stage)
        return None if node is None else node.cls.all_outputs().get(port)

    def by_type(self, cls: type[Message]) -> tuple[str, str] | None:
        read = {(e.src, e.src_port) for e in self.graph.edges}
        found = [
            (s, p)
            for s in self.played
            for p, t in self.graph.nodes[s].cls.all_outputs().items()
            if (s, p) in read and issubclass(cls, t)
        ]
        return found[0] if len(found) == 1 else None

    def readers(self, stage: str, port: str) -> list[tuple[str, str]]:
        return [(e.dst, e.dst_port) for e in self.graph.edges if e.src == stage and e.src_port == port]


def choose_target(
    ros_topic: str, cls: type[Message], names: Mapping[str, str], targets: RecipeTargets | None
) -> tuple[str, str]:
    """The (stage, port) ROS topic *ros_topic* (vgr type *cls*) becomes (module docstring's rules)."""
    if ros_topic in names:
        stage, port = split_target(names[ros_topic])
        if targets is not None:
            want = targets.port_type(stage, port)
            if stage not in targets.played or want is None or not issubclass(cls, want):
                raise ValueError(
                    f"--topic {ros_topic}={stage}/{port}: the recipe has no played-back stage {stage!r} with an "
                    f"output {port!r} of type {cls.TYPE} (played back: {', '.join(targets.played) or 'none'})"
                )
        return stage, port
    if targets is not None:
        hit = targets.subscribed.get(ros_topic)
        if hit is not None and (want := targets.port_type(*hit)) is not None and issubclass(cls, want):
            return hit
        hit = targets.by_type(cls)
        if hit is not None:
            return hit
    return derived_target(ros_topic)


def load_targets(recipe: str, overrides: list[str]) -> tuple[Any, RecipeTargets]:
    from engine.graph import build_graph
    from engine.plugin_manager import load_registry
    from engine.recipe.model import load_recipe

    loaded = load_recipe(recipe, overrides)
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    return loaded, RecipeTargets.of(graph)


def open_bag(bag: str | Path) -> Any:
    """An open rosbags reader of *bag* (a rosbag2 folder, or one .mcap / .db3 file); ValueError if none."""
    from rosbags.rosbag2 import Reader

    path = Path(bag)
    if not path.exists():
        raise FileNotFoundError(f"no such bag: {path}")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags' ReaderError, a yaml or sqlite error of a broken bag
        raise ValueError(f"{path} is not a readable rosbag2: {type(exc).__name__}: {exc}") from None
    return reader


def storage_of(reader: Any) -> str:
    """``mcap`` or ``sqlite3``: the storage of the open bag *reader*."""
    inner = getattr(reader.storage, "storages", None) or [reader.storage]
    kinds = {type(s).__name__ for s in inner}
    return "mcap" if "McapReader" in kinds else "sqlite3" if "Sqlite3Reader" in kinds else ",".join(sorted(kinds))


def plan_topics(
    reader: Any, names: Mapping[str, str], targets: RecipeTargets | None, report: ImportReport
) -> dict[int, ImportedTopic]:
    """Connection id -> the channel its messages go to; the connections vgr cannot take, skipped."""
    chosen: dict[int, ImportedTopic] = {}
    by_topic: dict[str, ImportedTopic] = {}
    for conn in reader.connections:
        if conn.msgtype not in SUPPORTED:
            reason = f"{conn.msgtype} has no vgr conversion"
        elif (fmt := getattr(conn.ext, "serialization_format", "cdr")) != "cdr":
            reason = f"serialised as {fmt}, not cdr"
        else:
            reason = ""
        if reason:
            if conn.topic not in {s["topic"] for s in report.skipped}:
                report.skipped.append({"topic": conn.topic, "type": conn.msgtype, "reason": reason})
            continue
        if conn.topic in by_topic:  # (a bag split in several files has a connection per file)
            chosen[conn.id] = by_topic[conn.topic]
            continue
        cls = SUPPORTED[conn.msgtype]
        stage, port = choose_target(conn.topic, cls, names, targets)
        t = ImportedTopic(conn.topic, conn.msgtype, f"/{stage}/{port}", cls.TYPE)
        if targets is not None:
            t.fed = [f"{s}.{p}" for s, p in targets.readers(stage, port)]
        chosen[conn.id] = by_topic[conn.topic] = t
    unknown = sorted(set(names) - set(by_topic))
    if unknown:
        raise ValueError(f"--topic names {', '.join(unknown)}, which the bag has no convertible topic of")
    types: dict[str, str] = {}
    for t in by_topic.values():
        if types.setdefault(t.vgr_topic, t.vgr_type) != t.vgr_type:
            raise ValueError(f"vgr topic {t.vgr_topic} would carry both {types[t.vgr_topic]} and {t.vgr_type}")
    return chosen


def _metadata(
    report: ImportReport, loaded: Any, start_ns: int, plugins: list[str], reader: Any, mapping: dict[str, str]
) -> dict[str, dict[str, str]]:
    recipe = loaded.recipe if loaded is not None else None
    name = recipe.name if recipe is not None else f"bag_{Path(report.bag).stem}"
    meta = {
        "vgr.run": {
            "run_id": (getattr(recipe, "run_id", None) or name) if recipe is not None else name,
            "process": "main",
            "seed": str(recipe.seed) if recipe is not None else "0",
            "clock": recipe.clock if recipe is not None else "sim",
            "recipe": name,
            "recipe_file": str(Path(loaded.file).resolve()) if loaded is not None and loaded.file else "",
            "started_utc": datetime.fromtimestamp(start_ns / 1e9, UTC).isoformat(),
            "clock_start_ns": str(start_ns),
        },
        "vgr.versions": _versions(plugins),
        "vgr.imported": {
            "bag": str(report.bag),
            "storage": report.storage,
            "ros_distro": str(getattr(reader, "ros_distro", "") or ""),
            "topics": json.dumps(mapping, sort_keys=True),
        },
    }
    if loaded is not None:
        meta["vgr.recipe"] = {
            "text": loaded.text,
            "overrides": json.dumps(loaded.overrides),
            "resolved_json": loaded.recipe.model_dump_json(),
        }
    return meta


def _versions(plugins: list[str]) -> dict[str, str]:
    import platform
    from importlib import metadata

    out = {"vgr": __version__, "python": platform.python_version(), "plugins": ",".join(plugins)}
    for pkg in ("rosbags", "numpy", "protobuf", "mcap"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[pkg] = metadata.version(pkg)
    return out


class _RecordingWriter:
    """The vgr recording being written: channels, messages, deliveries, finishes, summary."""

    def __init__(self, f: Any, meta: dict[str, dict[str, str]], recipe_text: str | None) -> None:
        from mcap.writer import CompressionType, Writer

        self.w = Writer(f, compression=CompressionType.ZSTD, enable_data_crcs=True)
        self.w.start(profile="", library=f"vgr {__version__} bag import")
        for name, record in meta.items():
            self.w.add_metadata(name, record)
        if recipe_text is not None:
            t = int(meta["vgr.run"]["clock_start_ns"])
            self.w.add_attachment(t, t, "recipe.yaml", "application/yaml", recipe_text.encode())
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.seq: dict[str, int] = {}

    def channel(self, topic: str, schema: str, meta: dict[str, str]) -> int:
        cid = self.channels.get(topic)
        if cid is None:
            sid = self.schemas.get(schema)
            if sid is None:
                sid = self.schemas[schema] = self.w.register_schema(schema, "protobuf", descriptor_set(schema))
            cid = self.channels[topic] = self.w.register_channel(topic, "protobuf", sid, meta)
        return cid

    def message(self, stage: str, port: str, msg: Message, log_time: int, role: str) -> int:
        topic = f"/{stage}/{port}"
        meta = {"stage": stage, "port": port, "type": msg.TYPE, "process": "main", "role": role}
        cid = self.channel(topic, msg.SCHEMA, meta)
        seq = self.seq[topic] = self.seq.get(topic, 0) + 1
        self.w.add_message(cid, log_time, codec.encode_payload(msg), msg.stamp_ns, seq & 0xFFFFFFFF)
        return seq

    def record(self, topic: str, type_name: str, kind: str, log_time: int, fields: dict[str, Any]) -> None:
        data = proto_class(type_name)(**fields).SerializeToString()
        cid = self.channel(topic, type_name, {"kind": kind})
        self.w.add_message(cid, log_time, data, log_time, 0)

    def finish(self, summary: dict[str, str]) -> None:
        self.w.add_metadata("vgr.summary", summary)
        self.w.finish()


def import_bag(
    bag: str | Path,
    output: str | Path,
    *,
    topics: Mapping[str, str] | None = None,
    recipe: str | None = None,
    overrides: list[str] | None = None,
    frames: Mapping[str, str] | None = None,
) -> ImportReport:
    """Write vgr recording *output* (a new file) from rosbag2 *bag*; *topics*: ROS topic -> ``stage/port``;
    *recipe*: the recipe whose stages the recording feeds (module docstring); *frames*: ROS -> vgr frames."""
    out = Path(output)
    if out.exists() or out.is_symlink():
        raise FileExistsError(f"{out} exists: vgr bag import writes a new file, choose another -o")
    names = {"/" + k.strip("/"): v for k, v in (topics or {}).items()}
    loaded, targets = load_targets(recipe, overrides or []) if recipe is not None else (None, None)
    reader = open_bag(bag)
    try:
        report = ImportReport(str(bag), str(out), storage_of(reader), recipe)
        chosen = plan_topics(reader, names, targets, report)
        if not chosen:
            raise NothingToImportError(f"no topic of {bag} has a type vgr converts", report.skipped)
        mapping = {t.ros_topic: t.vgr_topic for t in chosen.values()}
        plugins = list(loaded.recipe.plugins) if loaded is not None else []
        start = int(reader.start_time) if reader.message_count else 0  # (an empty bag has no start)
        meta = _metadata(report, loaded, start, plugins, reader, mapping)
        with create_new(out) as f:
            try:
                _write(reader, f, meta, loaded, targets, chosen, report, frames)
            except BaseException:
                f.close()
                out.unlink(missing_ok=True)  # (the file is the one this call created)
                raise
    finally:
        reader.close()
    report.topics = list({id(t): t for t in chosen.values()}.values())
    _explain(report, targets)
    if not report.messages_written:  # (the file is the one this call created)
        out.unlink(missing_ok=True)
        failed = [n for n in report.notes if n.endswith("(message skipped)")]
        why = f": {failed[0]}" if failed else " (its topics of convertible types hold no message)"
        raise NothingToImportError(f"no message of {bag} converts{why}", report.skipped)
    return report


def _write(
    reader: Any,
    f: Any,
    meta: dict[str, dict[str, str]],
    loaded: Any,
    targets: RecipeTargets | None,
    chosen: dict[int, ImportedTopic],
    report: ImportReport,
    frames: Mapping[str, str] | None,
) -> None:
    rw = _RecordingWriter(f, meta, loaded.text if loaded is not None else None)
    readers: dict[str, list[tuple[str, str]]] = {}
    last = int(meta["vgr.run"]["clock_start_ns"])
    for conn, timestamp, raw in reader.messages(connections=[c for c in reader.connections if c.id in chosen]):
        t = chosen[conn.id]
        try:
            msg = decode(conn.msgtype, raw, topic=conn.topic, frames=frames, notes=report.notes)
        except ConversionError as exc:
            t.failed += 1
            if t.failed <= 3:  # (the first few of a topic; the count says the rest)
                report.notes.append(f"{exc} (message skipped)")
            continue
        stage, port = t.vgr_topic[1:].split("/", 1)
        role = targets.graph.nodes[stage].cls.role if targets is not None and stage in targets.graph.nodes else "source"
        seq = rw.message(stage, port, msg, timestamp, role)
        t.messages += 1
        last = max(last, timestamp)
        if targets is None:
            continue
        dsts = readers.get(t.vgr_topic)
        if dsts is None:
            dsts = readers[t.vgr_topic] = targets.readers(stage, port)
        for dst, dst_port in dsts:
            fields = {"stage": dst, "port": dst_port, "source_topic": t.vgr_topic, "seq": seq}
            rw.record(TOPIC_DELIVERIES, "vgr.v1.Delivery", "deliveries", timestamp, fields)
            report.deliveries += 1
    if targets is not None:
        for name in targets.graph.order:
            if name not in targets.played:
                rw.record(TOPIC_FINISH, "vgr.v1.StageFinish", "finish", last, {"stage": name})
    rw.finish({"ok": "true", "outcome": "ok", "stop_reason": "", "wall_s": "0.000", "stop_to_end_s": "",
               "stages": "[]", "recording_error": "", "imported_from": str(report.bag)})  # fmt: skip


def _explain(report: ImportReport, targets: RecipeTargets | None) -> None:
    """Notes on what the recording will not do: topics no stage reads, stages fed by nothing."""
    for t in report.topics:
        if t.failed:
            report.notes.append(f"{t.ros_topic}: {t.failed} message(s) did not convert and were skipped")
    if targets is None:
        report.notes.append("no --recipe: the recording holds the data only (no stage is fed on replay)")
        return
    fed = {t.vgr_topic for t in report.topics}
    for t in report.topics:
        if not t.fed:
            report.notes.append(f"{t.ros_topic} -> {t.vgr_topic}: no stage of the recipe reads it")
    g = targets.graph
    for e in g.edges:
        src = f"/{e.src}/{e.src_port}"
        if e.src in targets.played and src not in fed:
            report.notes.append(f"{e.dst}.{e.dst_port} reads {src}, which the bag does not feed")
    for s in g.service_edges:
        if s.provider in targets.played and s.client not in targets.played:
            report.notes.append(
                f"{s.client} calls {s.provider}.{s.service}: a bag holds no service replies, that call fails on replay"
            )
