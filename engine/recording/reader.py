"""Reading vgr recordings: load a file into ordered records, summarise it, recover a crashed one.

:func:`load` returns a :class:`Recording` whose ``records`` keep the file's write order (the
order in which the run's observers saw things), which is what replay follows. :func:`recover`
rebuilds a file whose writer was killed (no summary/index): every chunk that reached the disk is
read back and written to a new, indexed file — the same job as ``mcap recover``.
"""

from __future__ import annotations

import json
import mmap
import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import CompressionType, Writer

from engine import __version__
from engine.files import replacing
from engine.messages.schemas import proto_class
from engine.recording.format import TOPIC_DELIVERIES, TOPIC_FINISH, TOPIC_SERVED


class RecordingError(RuntimeError):
    """The file is not a readable vgr recording (or needs ``vgr recover``)."""


@dataclass
class RecordedMessage:
    topic: str
    stage: str
    port: str
    type_name: str
    log_time: int
    publish_time: int
    seq: int
    payload: bytes


@dataclass
class Exchange:
    caller: str
    client: str
    provider: str
    service: str
    request_type: str
    request: bytes
    request_seq: int
    reply_type: str
    reply: bytes
    error: str
    log_time: int


@dataclass
class Recording:
    path: Path
    metadata: dict[str, dict[str, str]]
    channels: dict[str, dict[str, str]]  # topic -> channel metadata (+ schema)
    records: list[tuple[Any, ...]] = field(default_factory=list)  # ("msg", RecordedMessage) | ("deliver", ...)
    attachments: dict[str, bytes] = field(default_factory=dict)

    @property
    def recipe_text(self) -> str:
        return self.metadata.get("vgr.recipe", {}).get("text", "")

    @property
    def recipe_dir(self) -> Path | None:
        """The folder of the recorded recipe file, where its relative paths (templates, plugin
        files) start: see :func:`find_recipe_dir`. None when it is not found."""
        return find_recipe_dir(self.metadata.get("vgr.run", {}).get("recipe_file", ""), self.path)

    @property
    def overrides(self) -> list[str]:
        return json.loads(self.metadata.get("vgr.recipe", {}).get("overrides", "[]"))

    def messages(self, topic: str | None = None) -> list[RecordedMessage]:
        return [r[1] for r in self.records if r[0] == "msg" and (topic is None or r[1].topic == topic)]


def _records_from(schemas: dict[int, Schema], channels: dict[int, Channel], msg: Message) -> tuple[Any, ...] | None:
    ch = channels[msg.channel_id]
    if ch.topic == TOPIC_DELIVERIES:
        pb = proto_class("vgr.v1.Delivery")()
        pb.ParseFromString(msg.data)
        return ("deliver", pb.stage, pb.port, pb.source_topic, pb.seq, msg.log_time)
    if ch.topic == TOPIC_SERVED:
        pb = proto_class("vgr.v1.ServedCall")()
        pb.ParseFromString(msg.data)
        return ("served", pb.provider, pb.service, pb.caller_process, pb.caller_zid, pb.request_seq, pb.error)
    if ch.topic == TOPIC_FINISH:
        pb = proto_class("vgr.v1.StageFinish")()
        pb.ParseFromString(msg.data)
        return ("finish", pb.stage, msg.log_time)
    if "/_svc/" in ch.topic:
        pb = proto_class("vgr.v1.ServiceExchange")()
        pb.ParseFromString(msg.data)
        return (
            "svc",
            Exchange(
                pb.caller,
                pb.client,
                pb.provider,
                pb.service,
                pb.request_type,
                pb.request,
                pb.request_seq,
                pb.reply_type,
                pb.reply,
                pb.error,
                msg.log_time,
            ),
        )
    meta = ch.metadata
    return (
        "msg",
        RecordedMessage(
            ch.topic,
            meta.get("stage", ""),
            meta.get("port", ""),
            meta.get("type", ""),
            msg.log_time,
            msg.publish_time,
            msg.sequence,
            msg.data,
        ),
    )


class RecordingDamagedError(RecordingError):
    """The file's checksums do not match its bytes: it was changed after it was written (a disk, a copy)."""


_FOOTER = struct.Struct("<BQQQI")  # opcode, record length, summary_start, summary_offset_start, summary_crc
_DATA_END = 13  # opcode, record length, data_section_crc


def find_recipe_dir(recipe_file: str, recording: Path) -> Path | None:
    """Folder of the recorded recipe file *recipe_file* (as the run named it) of *recording*.

    A relative path is tried from the working directory, then from each folder above the recording
    (a golden recording in ``recordings/`` finds ``recipes/...`` of its checkout, wherever it is)."""
    if not recipe_file:
        return None
    rel = Path(recipe_file)
    candidates = [rel] if rel.is_absolute() else [rel, *(d / rel for d in Path(recording).resolve().parents)]
    for c in candidates:
        if c.is_file():
            return c.resolve().parent
    return None


def check_checksums(path: Path, data: bytes | memoryview) -> None:
    """The MCAP's own CRCs of what no chunk CRC covers: the data section as a whole (records between
    the chunks: metadata, the recipe) and the summary (RecordingDamagedError naming the byte range).
    A CRC of 0 means the writer did not compute it (recordings of older vgr versions)."""
    if len(data) < 8 + _FOOTER.size + 8 + _DATA_END or data[-8 - _FOOTER.size] != 0x02:
        return  # no footer: a file cut short (vgr recover), reported by the reader
    _, _, summary_start, _, summary_crc = _FOOTER.unpack_from(data, len(data) - 8 - _FOOTER.size)
    end_of_summary = len(data) - 8 - 4
    if summary_crc and summary_start and zlib.crc32(data[summary_start:end_of_summary]) != summary_crc:
        raise RecordingDamagedError(
            f"{path} is damaged: its summary (bytes {summary_start}-{end_of_summary}) does not match its CRC"
        )
    data_end = (summary_start or len(data) - 8 - _FOOTER.size) - _DATA_END
    if data_end < 8 or data[data_end] != 0x0F:
        return
    (data_crc,) = struct.unpack_from("<I", data, data_end + 9)
    if data_crc and zlib.crc32(data[:data_end]) != data_crc:
        raise RecordingDamagedError(
            f"{path} is damaged: its data (bytes 0-{data_end}) does not match its CRC; "
            f"`vgr recover {path}` salvages the chunks that are intact"
        )


def load(path: str | Path) -> Recording:
    """Read a whole recording (file order kept). Raises RecordingError with advice if it is damaged
    (RecordingDamagedError when a checksum says its bytes changed)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"no such recording: {path}")
    with path.open("rb") as f:
        if path.stat().st_size:  # (mapped, not read into memory: a recording may be gigabytes)
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mapped, memoryview(mapped) as data:
                check_checksums(path, data)
        try:
            reader = make_reader(f, validate_crcs=True)  # a flipped bit is a damaged file, not data
            summary = reader.get_summary()
            if summary is None:
                raise RecordingError(f"{path} has no summary (the run was killed?): run `vgr recover {path}`")
            schemas = dict(summary.schemas)
            channels = dict(summary.channels)
            rec = Recording(path, {}, {})
            for m in reader.iter_metadata():
                rec.metadata[m.name] = dict(m.metadata)
            for a in reader.iter_attachments():
                rec.attachments[a.name] = a.data
            for cid, ch in channels.items():
                rec.channels[ch.topic] = {
                    **ch.metadata,
                    "schema": schemas[ch.schema_id].name if ch.schema_id else "",
                    "channel_id": str(cid),
                }
            for _schema, _channel, message in reader.iter_messages(log_time_order=False):
                r = _records_from(schemas, channels, message)
                if r is not None:
                    rec.records.append(r)
        except RecordingError:
            raise
        except CRCValidationError as exc:
            raise RecordingDamagedError(
                f"{path} is damaged: {exc}; `vgr recover {path}` salvages the chunks that are intact"
            ) from None
        except Exception as exc:  # any failure to parse a damaged file (McapError,
            # zstd's ZstdError, OverflowError on a flipped length, ...) is the file's, not vgr's
            raise RecordingError(
                f"cannot read {path}: {type(exc).__name__}: {exc} (the file is damaged; if the run was killed, "
                f"try `vgr recover {path}`)"
            ) from None
    if "vgr.run" not in rec.metadata:
        raise RecordingError(f"{path} is an MCAP file but not a vgr recording (no vgr.run metadata)")
    return rec


def inspect(rec: Recording) -> dict[str, Any]:
    """Topics with counts, rates and time span; recipe, run and versions; service exchanges."""
    per_topic: dict[str, list[int]] = {}
    for r in rec.records:
        if r[0] == "msg":
            per_topic.setdefault(r[1].topic, []).append(r[1].log_time)
    svc = Counter(
        f"{r[1].caller}.{r[1].client} -> {r[1].provider}.{r[1].service}" for r in rec.records if r[0] == "svc"
    )
    topics = []
    for topic, times in sorted(per_topic.items()):
        span = (max(times) - min(times)) / 1e9 if len(times) > 1 else 0.0
        meta = rec.channels.get(topic, {})
        topics.append(
            {
                "topic": topic,
                "type": meta.get("type", ""),
                "schema": meta.get("schema", ""),
                "count": len(times),
                "rate_hz": (len(times) - 1) / span if span > 0 else None,
                "first_ns": min(times),
                "last_ns": max(times),
            }
        )
    all_times = [t for ts in per_topic.values() for t in ts]
    return {
        "path": str(rec.path),
        "size_bytes": rec.path.stat().st_size,
        "run": rec.metadata.get("vgr.run", {}),
        "summary": rec.metadata.get("vgr.summary", {}),
        "versions": rec.metadata.get("vgr.versions", {}),
        "recipe": rec.metadata.get("vgr.run", {}).get("recipe", ""),
        "time_span_s": (max(all_times) - min(all_times)) / 1e9 if all_times else 0.0,
        "topics": topics,
        "service_exchanges": dict(svc),
        "deliveries": sum(1 for r in rec.records if r[0] == "deliver"),
        "attachments": sorted(rec.attachments),
    }


@dataclass
class RecoverReport:
    source: str
    output: str
    messages: int
    chunks_ok: int
    complete: bool
    error: str
    last_log_time: int | None


def recover(src: str | Path, dst: str | Path | None = None, *, overwrite: bool = False) -> RecoverReport:
    """Copy every readable record of *src* (e.g. a file cut by kill -9) into a new indexed file.

    *src* is only read: the output may not be *src* itself, an existing output is replaced only with
    *overwrite*, and the output appears under its name only once it is complete (written beside it
    under a temporary name, then renamed). Raises RecordingError otherwise."""
    src = Path(src)
    dst = Path(dst) if dst else src.with_name(src.stem + "-recovered.mcap")
    if not src.is_file():
        raise RecordingError(f"no such recording: {src}")
    if dst.exists() and dst.resolve() == src.resolve():
        raise RecordingError(f"the output {dst} is the recording being recovered: choose another -o")
    if dst.exists() and not overwrite:
        raise RecordingError(f"{dst} exists: remove it, choose another -o, or pass --force")
    with replacing(dst) as tmp:
        report = _copy_readable(src, tmp, dst)
    return report


def _summary_records(f: Any) -> list[Any]:
    """The schema and channel records of the file's summary section, when it has a readable one."""
    try:
        f.seek(0)
        summary = make_reader(f).get_summary()
    except Exception:
        return []
    if summary is None:
        return []
    return [*summary.schemas.values(), *summary.channels.values()]


def _chunks_opened(records: Any, damaged: list[int]) -> Any:
    """The records of a stream, each chunk's opened; a chunk that does not open (CRC, compression)
    is skipped and its number (1 = the first chunk) noted in *damaged*, so the chunks after it are
    still recovered."""
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk

    k = 0
    for record in records:
        if not isinstance(record, Chunk):
            yield record
            continue
        k += 1
        try:
            inner = list(breakup_chunk(record, validate_crc=True))
        except Exception:
            damaged.append(k)
            continue
        yield from inner


def _copy_readable(src: Path, tmp: Path, dst: Path) -> RecoverReport:
    """recover()'s copy of *src* into *tmp* (reported as *dst*)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    out_schema: dict[int, int] = {}
    out_channel: dict[int, int] = {}
    n, last, error, complete = 0, None, "", False
    damaged: list[int] = []  # chunks whose CRC or compression is broken: skipped, the others kept
    lost = 0  # messages whose channel is known nowhere (its record was in a damaged chunk, no summary)
    with src.open("rb") as f, tmp.open("wb") as g:
        w = Writer(g, compression=CompressionType.ZSTD, enable_data_crcs=True)
        w.start(profile="", library=f"vgr {__version__} recover")
        for record in _summary_records(f):  # (a damaged chunk may have held a channel's only record)
            if isinstance(record, Schema):
                schemas[record.id] = record
                out_schema[record.id] = w.register_schema(record.name, record.encoding, record.data)
        for record in _summary_records(f):
            if isinstance(record, Channel) and record.schema_id in out_schema | {0: 0}:
                channels[record.id] = record
                schema = out_schema.get(record.schema_id, 0)
                out_channel[record.id] = w.register_channel(
                    record.topic, record.message_encoding, schema, dict(record.metadata)
                )
        f.seek(0)
        reader = StreamReader(f, skip_magic=False, emit_chunks=True, validate_crcs=True)
        try:
            for record in _chunks_opened(reader.records, damaged):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                    if record.id not in out_schema:
                        out_schema[record.id] = w.register_schema(record.name, record.encoding, record.data)
                elif isinstance(record, Channel):
                    channels[record.id] = record
                    if record.id not in out_channel:
                        out_channel[record.id] = w.register_channel(
                            record.topic,
                            record.message_encoding,
                            out_schema.get(record.schema_id, 0),
                            dict(record.metadata),
                        )
                elif isinstance(record, Message) and record.channel_id not in out_channel:
                    lost += 1
                elif isinstance(record, Message):
                    w.add_message(
                        out_channel[record.channel_id],
                        record.log_time,
                        record.data,
                        record.publish_time,
                        record.sequence,
                    )
                    n += 1
                    last = record.log_time if last is None else max(last, record.log_time)
                elif isinstance(record, Metadata):
                    w.add_metadata(record.name, dict(record.metadata))
                elif isinstance(record, Attachment):
                    w.add_attachment(record.create_time, record.log_time, record.name, record.media_type, record.data)
                elif type(record).__name__ == "Footer":
                    complete = True
        except Exception as exc:  # the truncated tail: everything before it is kept
            error = f"{type(exc).__name__}: {exc}"
        if not schemas and not channels and n == 0:  # nothing of a recording in it: write nothing
            if damaged:
                raise RecordingDamagedError(f"{src}: every chunk of it is damaged ({len(damaged)}): nothing to recover")
            raise RecordingError(f"{src} holds nothing to recover (not an MCAP recording?): {error or 'no records'}")
        if damaged:
            skipped = f"{len(damaged)} damaged chunk(s) skipped (number {', '.join(map(str, damaged))})"
            skipped += f", {lost} message(s) of unknown channels" if lost else ""
            error = f"{skipped}; {error}" if error else skipped
        w.add_metadata("vgr.recovered", {"from": str(src), "messages": str(n), "tail_error": error})
        w.finish()
    return RecoverReport(str(src), str(dst), n, 0, complete, error, last)
