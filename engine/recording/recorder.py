"""Recording a run to MCAP: every message, service exchange and delivery, with the recipe and versions.

One file per process: ``<recipe>.mcap`` in the run's folder (engine.run_folder), or the file
``--record`` / the recipe's ``record.path`` names. Contents:

* a channel per output port, topic ``/<stage>/<port>``, protobuf-encoded with the message's schema
  (Foxglove schemas for geometry, so Foxglove shows the 3D view); ``sequence`` = the message's seq,
  ``publish_time`` = its source stamp, ``log_time`` = the run's clock when it was published. Inputs
  that arrived from other processes are recorded on their producer's topic, so the file is
  self-contained;
* ``/<stage>/_svc/<client>`` (vgr.v1.ServiceExchange): every service call with request and reply;
* ``/_vgr/served`` (vgr.v1.ServedCall): every request a stage of this process served, with its caller:
  the caller's process, or empty when the calling zenoh session is not one of the run's, and its
  ZenohId (empty when the query did not say); a call from outside the run is there too;
* ``/_vgr/deliveries`` (vgr.v1.Delivery) and ``/_vgr/finish`` (vgr.v1.StageFinish): the order in
  which each stage handled its inputs, which replay follows instead of arrival order;
* ``/_vgr/run`` (vgr.v1.Event): the runner's own account of a stop, in order (engine.run.runner): ``stop``
  with its reason, ``halted`` per device stage (or ``halt_failed``), ``stage_stopped`` per stage the
  stop ended (``details.after_s``: seconds from the stop to its end), ``stage_stuck`` per stage still
  busy after the grace period, ``stop_done``; log time = the run's clock. A run that ends normally
  writes nothing there. (A stage's own events, ``move_halted`` or the ``stopped`` of a stage that
  met ``RunStoppingError``, are on its ``/<stage>/events``.)
* metadata ``vgr.run`` (run id, process, seed, clock, start), ``vgr.recipe`` (text, overrides,
  resolved parameters), ``vgr.versions`` (vgr, Python, packages, plugins), ``vgr.summary`` (at the
  end: outcome, stop reason, each stage's end state, ``stop_to_end_s``); the recipe text is also an
  attachment ``recipe.yaml``.

Chunked, compressed (zstd by default) and indexed. A writer thread owns the file; it closes the
current chunk and flushes to the OS at least every ``record.flush_interval_s`` (default 1 s), so a
``kill -9`` loses at most that much: ``vgr recover`` rebuilds the index of such a file.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import queue
import threading
import time
from datetime import datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcap.writer import CompressionType, Writer

from engine import __version__
from engine.files import create_new
from engine.messages import codec
from engine.messages.codec import Envelope
from engine.messages.schemas import descriptor_set, proto_class
from engine.recipe.model import LoadedRecipe, RecordSettings
from engine.recording.format import TOPIC_DELIVERIES, TOPIC_FINISH, TOPIC_RUN, TOPIC_SERVED, service_topic
from engine.run.runner import Observer, Runner, RunSummary
from engine.transport.bus import topic_of

if TYPE_CHECKING:
    from engine.messages import Event, Message
    from engine.run.stage_host import ServedCall, ServiceCall

log = logging.getLogger("vgr.recorder")

PACKAGES = (
    "numpy",
    "scipy",
    "open3d-cpu",
    "open3d",
    "eclipse-zenoh",
    "protobuf",
    "mcap",
    "pydantic",
    "pluggy",
    "small_gicp",
    "kiss-icp",
)
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def default_path(recipe: str, process: str, directory: str | Path = "runs") -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    suffix = "" if process == "main" else f"-{process}"
    return Path(directory) / f"{stamp}-{recipe}{suffix}.mcap"


def resolve_path(
    settings: RecordSettings, recipe: str, process: str, override: str | None = None, run_dir: Path | None = None
) -> Path:
    """Where this process records: *override* (``--record``) or ``record.path`` (a file, or a
    directory), else ``<run_dir>/<recipe>.mcap`` (engine.run_folder), else runs/. A generated name
    (a directory or runs/) never reuses an existing file, and a named file that exists is refused
    (ValueError): a run never replaces what another run, or the user, wrote. A recipe's
    ``record.path`` file is shared by all its processes, so processes other than ``main`` record
    beside it under ``<stem>-<process>``."""
    target = override or settings.path
    generated = target is None or Path(target).is_dir() or target.endswith("/")
    if target is None and run_dir is not None:
        path = Path(run_dir) / f"{recipe}.mcap"
    elif target is None:
        path = default_path(recipe, process)
    elif generated:
        path = default_path(recipe, process, Path(target))
    else:
        path = Path(target)
        if override is None and process != "main":
            path = path.with_name(f"{path.stem}-{process}{path.suffix}")
    if not generated and (path.exists() or path.is_symlink()):  # (a dangling link too)
        raise ValueError(
            f"{path} exists: a run never replaces a file; name a new file, or a folder to get a new name in it"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    return _unused(path) if generated else path


def _unused(path: Path) -> Path:
    """*path*, or ``<stem>-1``, ``<stem>-2`` ... beside it: the first name no file has."""
    n, candidate = 1, path
    while candidate.exists() or candidate.is_symlink():
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
        n += 1
    return candidate


def versions(plugins: list[str]) -> dict[str, str]:
    out = {"vgr": __version__, "python": platform.python_version(), "platform": platform.platform()}
    for pkg in PACKAGES:
        try:
            out[pkg] = importlib_metadata.version(pkg)
        except importlib_metadata.PackageNotFoundError:
            continue
    out["plugins"] = ",".join(plugins)
    return out


WRITER_FINISH_TIMEOUT_S = 60.0  # how long the end of a run waits for the writer's backlog


class Recorder(Observer):
    """Run observer writing the MCAP file from its own thread (stage threads only enqueue)."""

    def __init__(self, path: Path, settings: RecordSettings, loaded: LoadedRecipe, plugins: list[str]) -> None:
        # an existing file (a golden recording, say) is not truncated at the start: the run records
        # beside it and replaces it only when it ends well (a failed run leaves both)
        final = self.final_path = Path(path)
        self.path = _unused(final.with_name(f"{final.stem}.new{final.suffix}")) if final.exists() else final
        self.settings = settings
        self.loaded = loaded
        self.plugins = plugins
        self.error: str | None = None
        self.messages_written = 0
        self._q: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._runner: Runner | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seen_remote: set[tuple[str, int]] = set()
        self._run_seq = 0  # run events written (/_vgr/run)

    # -- observer interface (stage threads) ----------------------------------------------------
    def on_start(self, runner: Runner) -> None:
        self._runner = runner
        self._open_file(self.path)
        self._thread = threading.Thread(target=self._write_loop, name="vgr:recorder", daemon=True)
        self._thread.start()

    def _open_file(self, path: Path, extra: dict[str, dict[str, str]] | None = None) -> None:
        """Create *path* (a new file) and write its header: the run, the recipe (text and overrides),
        the versions, *extra* metadata records, the recipe as an attachment."""
        runner = self._runner
        assert runner is not None
        self._file = create_new(path)
        self._writer = Writer(
            self._file,
            chunk_size=self.settings.chunk_size,
            compression=_COMPRESSION[self.settings.compression],
            enable_data_crcs=True,  # (every chunk has its CRC; this one covers what lies between them too)
        )
        self._writer.start(profile="", library=f"vgr {__version__}")
        self._schemas, self._channels = {}, {}  # (ids are per file)
        recipe = self.loaded.recipe
        self._writer.add_metadata(
            "vgr.run",
            {
                "run_id": runner.run_id,
                "process": runner.process,
                "seed": str(recipe.seed),
                "clock": recipe.clock,
                "recipe": recipe.name,
                "recipe_file": self.loaded.file or "",
                "started_utc": runner.started_at.isoformat(),
                "clock_start_ns": str(runner.clock.now_ns()),
            },
        )
        self._writer.add_metadata(
            "vgr.recipe",
            {
                "text": self.loaded.text,
                "overrides": json.dumps(self.loaded.overrides),
                "resolved_json": recipe.model_dump_json(),
            },
        )
        self._writer.add_metadata("vgr.versions", versions(self.plugins))
        for name, record in (extra or {}).items():
            self._writer.add_metadata(name, record)
        self._writer.add_attachment(
            log_time=runner.clock.now_ns(),
            create_time=runner.clock.now_ns(),
            name="recipe.yaml",
            media_type="application/yaml",
            data=self.loaded.text.encode(),
        )

    def _now(self) -> int:
        assert self._runner is not None
        return self._runner.clock.now_ns()

    def on_publish(self, stage: str, port: str, payload: bytes, envelope: bytes, msg: Message) -> None:
        self._q.put(("msg", stage, port, msg.TYPE, self._now(), msg.stamp_ns, msg.seq, payload))

    def on_receive(self, src_stage: str, src_port: str, payload: bytes, envelope: bytes) -> None:
        env = codec.decode_envelope(envelope)
        self._q.put(("remote", src_stage, src_port, env.type_name, self._now(), env.stamp_ns, env.seq, payload))

    def on_deliver(self, stage: str, port: str, env: Envelope) -> None:
        assert self._runner is not None
        edge = next(e for e in self._runner.graph.inputs_of(stage) if e.dst_port == port)
        self._q.put(("deliver", stage, port, topic_of(edge.src, edge.src_port), env.seq, self._now()))

    def on_stage_finish(self, stage: str) -> None:
        self._q.put(("finish", stage, self._now()))

    def on_service(self, call: ServiceCall) -> None:
        req = codec.decode_envelope(call.req_env)
        reply_type = codec.decode_envelope(call.reply_env).type_name if call.reply_env else ""
        self._q.put(("svc", call, req.type_name, req.seq, reply_type, self._now()))

    def on_served(self, call: ServedCall) -> None:
        self._q.put(("served", call, self._now()))

    def on_run_event(self, ev: Event) -> None:
        self._q.put(("run", ev))  # (SimpleQueue.put: safe in the SIGINT handler too)

    def on_finish(self, runner: Runner, summary: RunSummary) -> None:
        self._q.put(("end", summary))
        if self._thread is not None:
            self._thread.join(WRITER_FINISH_TIMEOUT_S)
            if self._thread.is_alive():  # still writing a backlog: the file has no footer (yet)
                self.error = self.error or (
                    f"the recording writer did not finish within {WRITER_FINISH_TIMEOUT_S:g} s: "
                    f"{self.path} may lack its end (vgr recover restores what was written)"
                )
        if self.path != self.final_path:
            if summary.ok and not self.error:
                os.replace(self.path, self.final_path)
                self.path = self.final_path
            else:
                summary.artifacts["recording_kept"] = f"{self.final_path} was left as it was (the run did not end well)"
        summary.artifacts["recording"] = str(self.path)
        if self.error:
            summary.artifacts["recording_error"] = self.error

    # -- writer thread -----------------------------------------------------------------------
    def _write_loop(self) -> None:
        interval = self.settings.flush_interval_s
        last_flush = time.monotonic()
        dirty = False
        while True:
            # nothing unflushed: wait for the next item (a timeout of 0 here would spin a core while idle)
            timeout = max(0.0, interval - (time.monotonic() - last_flush)) if dirty else None
            try:
                item = self._q.get(timeout=timeout)
            except queue.Empty:
                item = None
            if item is not None and item[0] == "end":
                self._close(item[1])
                return
            if item is not None:
                try:
                    self._write(item)
                    dirty = True
                except Exception as exc:  # disk full, ...: keep draining, report at the end
                    if self.error is None:
                        self.error = f"{type(exc).__name__}: {exc}"
                        log.error("recording to %s failed: %s", self.path, exc)
            if dirty and time.monotonic() - last_flush >= interval:
                try:
                    self._writer.flush()
                except Exception as exc:
                    self.error = self.error or f"{type(exc).__name__}: {exc}"
                last_flush = time.monotonic()
                dirty = False

    def _schema(self, full_name: str) -> int:
        sid = self._schemas.get(full_name)
        if sid is None:
            sid = self._writer.register_schema(name=full_name, encoding="protobuf", data=descriptor_set(full_name))
            self._schemas[full_name] = sid
        return sid

    def _channel(self, topic: str, schema: str, meta: dict[str, str]) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._writer.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=self._schema(schema), metadata=meta
            )
            self._channels[topic] = cid
        return cid

    def _write(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        assert self._runner is not None
        if kind in ("msg", "remote"):
            _, stage, port, type_name, log_time, stamp, seq, payload = item
            topic = topic_of(stage, port)
            if kind == "remote":
                if (topic, seq) in self._seen_remote:
                    return
                self._seen_remote.add((topic, seq))
            cls = codec.registry.get(type_name)
            node = self._runner.graph.nodes[stage]
            cid = self._channel(
                topic,
                cls.SCHEMA,
                {"stage": stage, "port": port, "type": type_name, "process": node.spec.process, "role": node.cls.role},
            )
            self._writer.add_message(
                channel_id=cid, log_time=log_time, data=bytes(payload), publish_time=stamp, sequence=seq & 0xFFFFFFFF
            )
            self.messages_written += 1
        elif kind == "deliver":
            _, stage, port, src_topic, seq, log_time = item
            fields = {"stage": stage, "port": port, "source_topic": src_topic, "seq": seq}
            self._add_record(TOPIC_DELIVERIES, "vgr.v1.Delivery", {"kind": "deliveries"}, log_time, fields)
        elif kind == "run":
            ev = item[1]
            meta = {"stage": "_vgr", "port": "run", "type": ev.TYPE, "kind": "run"}
            cid = self._channel(TOPIC_RUN, ev.SCHEMA, meta)
            self._run_seq += 1
            self._writer.add_message(
                channel_id=cid,
                log_time=ev.stamp_ns,
                data=codec.encode_payload(ev),
                publish_time=ev.stamp_ns,
                sequence=self._run_seq,
            )
        elif kind == "served":
            _, served, log_time = item
            fields = {
                "provider": served.stage,
                "service": served.service,
                "caller_process": served.caller_process,
                "caller_zid": served.caller_zid,
                "request_type": served.request_type,
                "request_seq": served.request_seq,
                "error": served.error,
            }
            self._add_record(TOPIC_SERVED, "vgr.v1.ServedCall", {"kind": "served"}, log_time, fields)
        elif kind == "finish":
            _, stage, log_time = item
            self._add_record(TOPIC_FINISH, "vgr.v1.StageFinish", {"kind": "finish"}, log_time, {"stage": stage})
        elif kind == "svc":
            _, call, req_type, req_seq, reply_type, log_time = item
            stage, client, provider, service = call.stage, call.client, call.edge.provider, call.edge.service
            fields = {
                "caller": stage,
                "client": client,
                "provider": provider,
                "service": service,
                "request_type": req_type,
                "request": bytes(call.req_payload),
                "request_seq": req_seq,
                "reply_type": reply_type,
                "reply": bytes(call.reply_payload),
                "error": call.error,
            }
            meta = {"stage": stage, "client": client, "provider": provider, "service": service}
            topic = service_topic(stage, client)
            self._add_record(topic, "vgr.v1.ServiceExchange", meta, log_time, fields, sequence=req_seq & 0xFFFFFFFF)

    def _add_record(
        self, topic: str, type_name: str, meta: dict[str, str], log_time: int, fields: dict[str, Any], sequence: int = 0
    ) -> None:
        """Write the engine's own record *type_name* (a vgr.v1 protobuf made of *fields*) on *topic*,
        published at its *log_time*."""
        data = proto_class(type_name)(**fields).SerializeToString()
        cid = self._channel(topic, type_name, meta)
        self._writer.add_message(channel_id=cid, log_time=log_time, data=data, publish_time=log_time, sequence=sequence)

    def _close(self, summary: RunSummary) -> None:
        self._finish_file(self._summary_record(summary))

    def _finish_file(self, summary: dict[str, str]) -> None:
        """Write *summary* (metadata ``vgr.summary``), the index and the footer; close the file."""
        try:
            self._writer.add_metadata("vgr.summary", summary)
            self._writer.finish()
        except Exception as exc:
            self.error = self.error or f"{type(exc).__name__}: {exc}"
        finally:
            self._file.close()

    def _summary_record(self, summary: RunSummary) -> dict[str, str]:
        return {
            "ok": str(summary.ok).lower(),
            "outcome": summary.outcome,
            "stop_reason": summary.stop_reason or "",
            "wall_s": f"{summary.wall_s:.3f}",
            "stop_to_end_s": "" if summary.stop_to_end_s is None else f"{summary.stop_to_end_s:.3f}",
            "stages": json.dumps(
                [
                    {
                        "name": s.name,
                        "state": s.state,
                        "in": s.messages_in,
                        "out": s.messages_out,
                        "errors": s.errors,
                    }
                    for s in summary.stages
                ]
            ),
            "recording_error": self.error or "",
        }
