"""A recording made anew from a replay (``vgr replay --update``): the replayed outputs and requests
in place of the recorded ones, everything else (schemas, channels, metadata, attachments, the
played-back inputs) copied as recorded; the recipe replaced when the replay used another one.

The new file is written beside the old one and renamed over it (engine.files.replacing), so a
golden recording is never left half-written. A replay during which a stage failed is refused: the
failed stage stopped producing, and its later golden outputs would be dropped.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from engine.files import replacing
from engine.messages import codec
from engine.messages.schemas import descriptor_set
from engine.recording.reader import Recording
from engine.recording.replay import ReplayError, ReplayReport


def write_updated(
    report: ReplayReport,
    rec: Recording,
    out: str | Path,
    recipe_text: str | None = None,
    overrides: list[str] | None = None,
) -> Path:
    """Write *rec* with the replayed outputs (and requests) in place of the recorded ones: the new golden.

    *recipe_text* and *overrides* (those the replay used) replace the recorded recipe when given.

    Written to a temporary file and renamed, so the golden recording is never left half-written.
    """
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    if report.failures:  # a failed stage stopped producing: its later golden outputs would be dropped
        raise ReplayError(f"not updating {out}: a stage failed during the replay ({report.failures[0]})")
    out = Path(out)
    counters: dict[str, int] = defaultdict(int)
    svc_sent = {f"/{c}/_svc/{k}": v for (c, k), v in report.requests_sent.items()}
    with replacing(out) as tmp, rec.path.open("rb") as f, tmp.open("wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        w = Writer(g, compression=CompressionType.ZSTD)
        w.start(profile="", library="vgr replay --update")
        schema_ids = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        chan_ids = {
            cid: w.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata))
            for cid, c in summary.channels.items()
        }
        topic_chan = {c.topic: chan_ids[cid] for cid, c in summary.channels.items()}
        for m in reader.iter_metadata():
            data = dict(m.metadata)
            if m.name == "vgr.recipe" and recipe_text is not None:
                data["text"] = recipe_text
                data["overrides"] = json.dumps(overrides or [])
            w.add_metadata(m.name, data)
        for a in reader.iter_attachments():
            data = recipe_text.encode() if (a.name == "recipe.yaml" and recipe_text is not None) else a.data
            w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, data)
        last = 0
        rerun_topics = set(report.outputs) | {v.topic for v in report.streams}
        for _s, ch, msg in reader.iter_messages(log_time_order=False):
            last = max(last, msg.log_time)
            data, seq, pub = msg.data, msg.sequence, msg.publish_time
            if ch.topic in rerun_topics:
                k = counters[ch.topic]
                counters[ch.topic] += 1
                outs = report.outputs.get(ch.topic, [])
                if k >= len(outs):
                    continue  # the replay produced fewer messages: they are gone from the golden
                data, seq, pub = outs[k].payload, outs[k].seq, outs[k].stamp_ns
            elif ch.topic in svc_sent:
                k = counters[ch.topic]
                counters[ch.topic] += 1
                pb = _exchange_pb(msg.data)
                if k < len(svc_sent[ch.topic]):
                    pb.request = svc_sent[ch.topic][k][1]
                data = pb.SerializeToString()
            w.add_message(chan_ids[ch.id], msg.log_time, data, pub, seq & 0xFFFFFFFF)
        for topic, outs in report.outputs.items():  # extra replayed messages (and topics new to the file)
            for o in outs[counters.get(topic, 0) :]:
                if topic not in topic_chan:
                    topic_chan[topic] = _new_channel(w, topic, o.type_name)
                w.add_message(topic_chan[topic], last, o.payload, o.stamp_ns, o.seq & 0xFFFFFFFF)
        w.add_metadata("vgr.updated", {"by": "vgr replay --update", "rerun": ",".join(report.rerun)})
        w.finish()
    return out


def _new_channel(w: Any, topic: str, type_name: str) -> int:
    cls = codec.registry.get(type_name)
    sid = w.register_schema(cls.SCHEMA, "protobuf", descriptor_set(cls.SCHEMA))
    stage, port = topic.strip("/").split("/", 1)
    return int(w.register_channel(topic, "protobuf", sid, {"stage": stage, "port": port, "type": type_name}))


def _exchange_pb(data: bytes) -> Any:
    from engine.messages.schemas import proto_class

    pb = proto_class("vgr.v1.ServiceExchange")()
    pb.ParseFromString(data)
    return pb
