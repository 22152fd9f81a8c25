"""``vgr bag export RUN.mcap -o DIR``: a vgr recording as a rosbag2 (MCAP storage, CDR, standard types).

Every data channel of the recording (``/<stage>/<port>``) whose vgr type has a ROS 2 standard type
(plugins.ros2.convert: ``ROS_TYPES``) becomes a topic of the bag, by default of the same name
(``/camera/cloud``), or the name ``--topic /camera/cloud=/camera/depth/points`` gives it. Several
channels may share one ROS topic (``--topic robot/frames=/tf --topic camera/frames=/tf``). Each
message is written at its recorded log time (the run's clock when it was published), its header
stamp being its source stamp. The engine's own records (``/_vgr/*``), service exchanges and
channels of other types (events, corrections, requests, scene meshes, plugin types) are skipped,
each with a note naming the topic. A topic sent to ``/tf_static`` is offered transient-local, as
ROS 2's static broadcaster does, so ``ros2 bag play`` latches it.

The bag is written by ``rosbags`` (rosbag2 metadata version 9, ROS 2 Jazzy message definitions and
type hashes): ``ros2 bag info`` / ``ros2 bag play`` (Jazzy and later) and the ``rosbags`` reader
read it. DIR must not exist (nor be a link): it is created, and removed again if the export fails.
"""

from __future__ import annotations

import contextlib
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine.messages import WIRE_CACHE, Message, codec
from engine.recording.format import service_topic
from engine.recording.reader import RecordedMessage, load
from plugins.ros2.convert import ConversionError, FrameMap, ros_type_of, to_ros
from plugins.ros2.convert_common import NothingConvertedError, typestore

TF_STATIC = "/tf_static"


class NothingToExportError(NothingConvertedError):
    """No channel of the recording converts: nothing is written (exit code 1); ``skipped`` says why."""


@dataclass
class ExportedTopic:
    vgr_topic: str
    vgr_type: str
    ros_topic: str
    ros_type: str
    messages: int = 0


@dataclass
class ExportReport:
    recording: str
    output: str
    topics: list[ExportedTopic] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)  # {topic, type, reason}
    notes: list[str] = field(default_factory=list)

    @property
    def messages_written(self) -> int:
        return sum(t.messages for t in self.topics)


def recorded_message(cls: type[Message], m: RecordedMessage) -> Message:
    """The message of record *m*, as replay gives it to a stage (stamp from the record when the
    payload has none), carrying its wire form so that its poses' quaternions go out unchanged."""
    if cls.WIRE_EXACT:
        msg = codec.decode_payload(cls, m.payload)
    else:
        pb = cls.proto()
        pb.ParseFromString(m.payload)
        msg = cls.from_proto(pb, None)
        msg.__dict__[WIRE_CACHE] = (pb, None)
    msg.seq = m.seq
    if not msg.stamp_ns:
        msg.stamp_ns = m.publish_time
    return msg


def ros_name(topic: str) -> str:
    """*topic* as a valid ROS 2 topic name: characters other than letters, digits, ``_`` and ``/``
    become ``_``, a level starting with a digit gets a ``_`` before it, empty levels go."""
    levels = [re.sub(r"[^A-Za-z0-9_]", "_", p) for p in topic.split("/") if p]
    return "/" + "/".join(f"_{p}" if p[0].isdigit() else p for p in levels)


def _ros_topic(vgr_topic: str, names: Mapping[str, str], report: ExportReport) -> str:
    if vgr_topic in names:
        return names[vgr_topic]
    valid = ros_name(vgr_topic)
    if valid != vgr_topic:
        report.notes.append(f"{vgr_topic} is written as {valid} (a valid ROS 2 topic name)")
    return valid


def plan(messages: list[RecordedMessage], names: Mapping[str, str], report: ExportReport) -> dict[str, ExportedTopic]:
    """vgr topic -> what it becomes in the bag, for the channels that convert (the others skipped)."""
    out: dict[str, ExportedTopic] = {}
    seen: set[str] = set()
    for m in messages:
        if m.topic in seen:
            continue
        seen.add(m.topic)
        cls = codec.registry.get(m.type_name) if m.type_name in codec.registry else None
        ros_type = ros_type_of(cls) if cls is not None else None
        if ros_type is None:
            reason = f"vgr type {m.type_name or '?'} has no ROS 2 standard type"
            report.skipped.append({"topic": m.topic, "type": m.type_name, "reason": reason})
            continue
        out[m.topic] = ExportedTopic(m.topic, m.type_name, _ros_topic(m.topic, names, report), ros_type)
    unknown = sorted(set(names) - set(out))
    if unknown:
        raise ValueError(f"--topic names {', '.join(unknown)}, which the recording has no convertible channel of")
    by_ros: dict[str, str] = {}
    for t in out.values():
        if by_ros.setdefault(t.ros_topic, t.ros_type) != t.ros_type:
            raise ValueError(f"ROS topic {t.ros_topic} would carry both {by_ros[t.ros_topic]} and {t.ros_type}")
    return out


def _qos(ros_topic: str) -> list[Any]:
    """The offered QoS of *ros_topic* in the bag's metadata (transient local for /tf_static)."""
    if ros_topic != TF_STATIC:
        return []
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(sec=0, nsec=0)  # (rosbag2's "default": no deadline, lifespan or lease)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            1,
            QosReliability.RELIABLE,
            QosDurability.TRANSIENT_LOCAL,
            never,
            never,
            QosLiveliness.AUTOMATIC,
            never,
            False,
        ),
    ]


def export_bag(
    recording: str | Path,
    output: str | Path,
    *,
    topics: Mapping[str, str] | None = None,
    frames: Mapping[str, str] | None = None,
) -> ExportReport:
    """Write the rosbag2 *output* (a new folder) from vgr recording *recording*; *topics*: vgr
    topic -> ROS topic, *frames*: ROS frame -> vgr frame (used backwards here)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    out_dir = Path(output)
    if out_dir.exists() or out_dir.is_symlink():
        raise FileExistsError(f"{out_dir} exists: vgr bag export writes a new folder, choose another -o")
    names = {"/" + k.strip("/"): "/" + v.strip("/") for k, v in (topics or {}).items()}
    bad = sorted(v for v in names.values() if ros_name(v) != v)
    if bad:
        raise ValueError(f"--topic: {', '.join(bad)} is not a ROS 2 topic name (letters, digits, _ and /)")
    rec = load(recording)
    report = ExportReport(str(recording), str(out_dir))
    data = [r[1] for r in rec.records if r[0] == "msg" and r[1].stage and not r[1].stage.startswith("_")]
    for topic in sorted({service_topic(r[1].caller, r[1].client) for r in rec.records if r[0] == "svc"}):
        report.skipped.append({"topic": topic, "type": "ServiceExchange", "reason": "a service exchange"})
    chosen = plan(data, names, report)
    if not chosen:
        raise NothingToExportError(f"no channel of {recording} has a ROS 2 standard type", report.skipped)
    fmap = FrameMap(frames or {}, strict=isinstance(frames, FrameMap) and frames.strict)
    store = typestore()
    writer = Writer(out_dir, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()  # (creates the folder; refuses one that appeared meanwhile)
    try:
        run = rec.metadata.get("vgr.run", {})
        writer.set_custom_data("vgr.recording", str(recording))  # (provenance, in metadata.yaml)
        writer.set_custom_data("vgr.run_id", run.get("run_id", ""))
        writer.set_custom_data("vgr.recipe", run.get("recipe", ""))
        conns: dict[str, Any] = {}
        for t in chosen.values():
            if t.ros_topic not in conns:
                conns[t.ros_topic] = writer.add_connection(
                    t.ros_topic, t.ros_type, typestore=store, offered_qos_profiles=_qos(t.ros_topic)
                )
        for m in sorted((m for m in data if m.topic in chosen), key=lambda m: m.log_time):
            t = chosen[m.topic]
            msg = recorded_message(codec.registry.get(m.type_name), m)
            ros = to_ros(msg, t.ros_type, frames=fmap, topic=m.topic)
            writer.write(conns[t.ros_topic], m.log_time, store.serialize_cdr(ros, t.ros_type))
            t.messages += 1
        writer.close()
    except BaseException:
        _remove(writer, out_dir)
        raise
    report.topics = list(chosen.values())
    return report


def _remove(writer: Any, out_dir: Path) -> None:
    """Undo a failed export: the folder is vgr's own (the writer made it just now), so it goes."""
    with contextlib.suppress(Exception):  # (the folder goes anyway)
        writer.abort()
    if out_dir.is_dir() and not out_dir.is_symlink():
        shutil.rmtree(out_dir, ignore_errors=True)


__all__ = ["ConversionError", "ExportReport", "ExportedTopic", "NothingToExportError", "export_bag", "recorded_message"]
