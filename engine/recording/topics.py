"""Looking at a running run from outside, as ``ros2 topic`` does: find it, list its topics, echo its
messages decoded, measure their rates (the ``vgr topics`` verbs, engine.cli.topics).

The tool is an ordinary foreign subscriber: a zenoh session that listens on nothing and connects to
the runs' endpoints (``--connect``, else the private unix sockets of this user's runs on this host,
engine.transport.endpoints: a single-process run has one with ``--listen private``), finds the runs by their
``_info`` documents (engine.transport.discovery) and decodes each
sample with the envelope of docs/zenoh_layout.md and the schema the run published, not with vgr's
message classes: what it shows is what any subscriber gets. Every loop here ends: after ``count``
messages or ``timeout_s`` (echo), after its windows (hz).
"""

from __future__ import annotations

import base64
import itertools
import math
import queue
import statistics
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory

from engine.messages import codec
from engine.recipe.model import ZenohSettings
from engine.transport.bus import Bus
from engine.transport.discovery import find_runs
from engine.transport.endpoints import private_socket_dir

BYTES_SHOWN = 48  # longer bytes fields (point data, images) are shown as their length


class NoRunError(ValueError):
    """No run (or no such run, or no such topic) to look at: exit code 2."""


def open_client(endpoints: list[str], certs: str | None = None, identity: str | None = None) -> Bus:
    """A session that listens on nothing and connects to *endpoints*; with *certs* (a folder of
    ``ca.pem`` and ``<identity>.pem/.key``), over mutual TLS as *identity*, an observer the secured
    run's ``security.observers`` names (docs/security.md)."""
    if not endpoints:
        raise NoRunError(
            f"no vgr run found: no run of this user listens on a private socket in {private_socket_dir()}; "
            "start one with `vgr run RECIPE --listen private` (a single-process run opens no listener "
            "otherwise), or name its endpoint with --connect"
        )
    extra = None
    if certs is not None:
        from engine.security.tls import folder_identity, tls_entries

        if identity is None:
            raise NoRunError("--certs needs --identity NAME: the observer certificate to show the run")
        extra = tls_entries(folder_identity(Path(certs), identity))
    return Bus(ZenohSettings(listen=[], connect=list(endpoints)), extra)


@dataclass
class Run:
    """A run as its processes describe themselves (engine.transport.discovery)."""

    run_id: str
    docs: list[dict[str, Any]]
    topics: list[dict[str, Any]] = field(default_factory=list)
    schemas: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for doc in sorted(self.docs, key=lambda d: str(d.get("process"))):
            for t in doc.get("topics", []):
                self.topics.append({**t, "process": doc.get("process", "")})
            self.schemas.update(doc.get("schemas", {}))

    def topic(self, name: str) -> dict[str, Any]:
        """The topic *name* (``/stage/port``, ``stage/port`` or ``stage.port``)."""
        bare = name.strip("/")
        wanted = "/" + (bare if "/" in bare else bare.replace(".", "/", 1))
        for t in self.topics:
            if t["topic"] == wanted:
                return t
        known = ", ".join(t["topic"] for t in self.topics)
        raise NoRunError(f"run {self.run_id} has no topic {name!r}; its topics: {known}")


def choose_run(bus: Bus, run_id: str | None, timeout_s: float = 1.0) -> Run:
    """The run *run_id*, or the only run reachable; NoRunError naming the runs found otherwise."""
    deadline = time.monotonic() + max(timeout_s, 0.1)
    runs = find_runs(bus, timeout_s, run_id)
    while not runs and time.monotonic() < deadline:  # a connection just made may need a moment
        time.sleep(0.1)
        runs = find_runs(bus, timeout_s, run_id)
    if run_id is not None:
        if run_id not in runs:
            found = ", ".join(sorted(find_runs(bus, timeout_s))) or "none"  # what there is, to say so
            raise NoRunError(f"no run {run_id!r} on the bus (runs found: {found})")
        return Run(run_id, runs[run_id])
    if not runs:
        raise NoRunError("no vgr run answered on the bus (has it ended?)")
    if len(runs) > 1:
        raise NoRunError(f"several runs are running, choose one with --run-id: {', '.join(sorted(runs))}")
    (only,) = runs
    return Run(only, runs[only])


class SchemaPool:
    """Message classes built from published ``FileDescriptorSet`` s alone (base64, as in ``_info``)."""

    def __init__(self, schemas: dict[str, str]) -> None:
        self._pool = descriptor_pool.DescriptorPool()
        self._encoded = schemas
        self._classes: dict[str, Any] = {}

    def message_class(self, full_name: str) -> Any:
        cls = self._classes.get(full_name)
        if cls is None:
            fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(self._encoded[full_name]))
            for fd in fds.file:
                try:
                    self._pool.FindFileByName(fd.name)
                except KeyError:
                    self._pool.Add(fd)
            cls = self._classes[full_name] = message_factory.GetMessageClass(
                self._pool.FindMessageTypeByName(full_name)
            )
        return cls


def _shorten(pb: Any, doc: dict[str, Any]) -> dict[str, Any]:
    """*doc* (``MessageToDict`` of *pb*) with long bytes fields replaced by ``"<N bytes>"``."""
    for f in pb.DESCRIPTOR.fields:
        if f.name not in doc:
            continue
        value = getattr(pb, f.name)
        if f.type == f.TYPE_BYTES and not isinstance(value, list | tuple) and len(value) > BYTES_SHOWN:
            doc[f.name] = f"<{len(value)} bytes>"
        elif f.message_type is not None and not f.message_type.GetOptions().map_entry:
            if isinstance(doc[f.name], list):
                doc[f.name] = [_shorten(v, d) for v, d in zip(value, doc[f.name], strict=False)]
            elif isinstance(doc[f.name], dict):
                doc[f.name] = _shorten(value, doc[f.name])
    return doc


def decode_sample(topic: dict[str, Any], payload: bytes, attachment: bytes, pool: SchemaPool) -> dict[str, Any]:
    """One sample as plain data: its envelope's seq, stamp and type, and the message by its schema."""
    env = codec.decode_envelope(attachment)
    if env.kind != codec.Kind.DATA:
        return {"topic": topic["topic"], "kind": env.kind.name.lower(), "seq": env.seq}
    try:
        pb = pool.message_class(topic["schema"]).FromString(payload)
    except Exception as exc:  # protobuf's DecodeError: a sample that is not what its topic says
        raise codec.CodecError(f"{topic['topic']}: cannot decode {topic['schema']}: {exc}") from None
    doc = json_format.MessageToDict(pb, preserving_proto_field_name=True)
    return {
        "topic": topic["topic"],
        "seq": env.seq,
        "stamp_ns": env.stamp_ns,
        "type": env.type_name,
        "message": _shorten(pb, doc),
    }


def _subscribe(bus: Bus, keys: list[str]) -> queue.SimpleQueue[tuple[float, str, bytes, bytes]]:
    """(monotonic arrival time, key, payload, attachment) of every sample on *keys*, queued."""
    q: queue.SimpleQueue[tuple[float, str, bytes, bytes]] = queue.SimpleQueue()

    def on_sample(sample: Any) -> None:
        att = sample.attachment
        q.put((time.monotonic(), str(sample.key_expr), sample.payload.to_bytes(), att.to_bytes() if att else b""))

    for key in keys:
        bus.subscribe(key, on_sample)
    return q


def echo(bus: Bus, run: Run, names: list[str], count: int, timeout_s: float) -> Iterator[dict[str, Any]]:
    """Up to *count* decoded messages of the topics *names*, as they arrive, for at most *timeout_s*."""
    topics = {t["key"]: t for t in (run.topic(n) for n in names)}
    pool = SchemaPool(run.schemas)
    q = _subscribe(bus, list(topics))
    deadline = time.monotonic() + timeout_s
    shown = 0
    while shown < count:
        left = deadline - time.monotonic()
        if left <= 0:
            return
        try:
            _, key, payload, att = q.get(timeout=left)
        except queue.Empty:
            return
        yield decode_sample(topics[key], payload, att, pool)
        shown += 1


@dataclass
class Rate:
    topic: str
    messages: int
    window_s: float
    rate_hz: float | None  # (messages - 1) / (last - first arrival); None below two messages
    gap_mean_ms: float | None = None
    gap_min_ms: float | None = None
    gap_max_ms: float | None = None
    gap_std_ms: float | None = None


def rates(arrivals: dict[str, list[float]], window_s: float) -> list[Rate]:
    """The rate of each topic from its arrival times (seconds) within one window."""
    out = []
    for topic, times in arrivals.items():
        if len(times) < 2:
            out.append(Rate(topic, len(times), window_s, None))
            continue
        gaps = [b - a for a, b in itertools.pairwise(times)]
        mean, std = statistics.fmean(gaps), statistics.pstdev(gaps)
        out.append(
            Rate(topic, len(times), window_s, 1.0 / mean if mean > 0 else math.inf, mean * 1e3, min(gaps) * 1e3,
                 max(gaps) * 1e3, std * 1e3)
        )  # fmt: skip
    return out


def hz(bus: Bus, run: Run, names: list[str], window_s: float, windows: int) -> Iterator[list[Rate]]:
    """The rates of the topics *names* over *windows* consecutive windows of *window_s* seconds."""
    topics = {t["key"]: t["topic"] for t in (run.topic(n) for n in names)}
    q = _subscribe(bus, list(topics))
    for _ in range(windows):
        arrivals: dict[str, list[float]] = {t: [] for t in topics.values()}
        end = time.monotonic() + window_s
        while (left := end - time.monotonic()) > 0:
            try:
                t, key, _, att = q.get(timeout=left)
            except queue.Empty:
                break
            if att[4:5] == bytes((codec.Kind.DATA,)):  # data only, not an end of stream
                arrivals[topics[key]].append(t)
        yield rates(arrivals, window_s)
