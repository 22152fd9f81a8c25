"""What a running process tells the bus about itself: its topics, their types and their schemas.

Every process of a run (and ``vgr play``) answers queries on ``vgr/<run>/_info/<process>`` with one
JSON document (UTF-8), the same for every query::

    {"layout": 1,                       # LAYOUT_VERSION: the key and attachment layout of
                                        # docs/zenoh_layout.md (also byte 3 of every envelope)
     "run_id": "demo", "process": "main", "vgr": "0.1.0", "source": "run" | "play",
     "topics": [{"key": "vgr/demo/move/cloud", "topic": "/move/cloud", "stage": "move",
                 "port": "cloud", "type": "PointCloud", "schema": "foxglove.PointCloud",
                 "encoding": "protobuf"}, ...],
     "schemas": {"foxglove.PointCloud": "<base64 of a serialised FileDescriptorSet>", ...}}

A schema is the same ``FileDescriptorSet`` vgr writes as the MCAP schema record
(:func:`engine.messages.schemas.descriptor_set`), so a foreign subscriber needs zenoh and a protobuf library,
nothing of vgr. ``vgr topics`` finds runs by querying ``vgr/*/_info/*``. The queryable is declared by
the runner when the process's outputs exist and goes with its session; it is a read-only account:
it answers nothing else and takes no input.
"""

from __future__ import annotations

import base64
import json
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from engine import __version__
from engine.transport.bus import data_key, topic_of

if TYPE_CHECKING:
    from engine.graph import Graph
    from engine.transport.bus import Bus

LAYOUT_VERSION = 1
ALL_INFO = "vgr/*/_info/*"


def info_key(run: str, process: str) -> str:
    return f"vgr/{run}/_info/{process}"


@dataclass(frozen=True)
class TopicInfo:
    key: str  # zenoh key of the public stream
    topic: str  # /<stage>/<port>, as in recordings
    stage: str
    port: str
    type: str  # vgr message type name (the envelope's)
    schema: str  # fully qualified protobuf message name
    encoding: str = "protobuf"


def topic_info(run_id: str, stage: str, port: str, type_name: str, schema: str) -> TopicInfo:
    return TopicInfo(data_key(run_id, stage, port), topic_of(stage, port), stage, port, type_name, schema)


def graph_topics(graph: Graph, run_id: str, process: str) -> list[TopicInfo]:
    """The output streams of the stages of *process*, events ports included."""
    topics = []
    for name in graph.stages_in(process):
        for port, cls in sorted(graph.nodes[name].cls.all_outputs().items()):
            topics.append(topic_info(run_id, name, port, cls.TYPE, cls.SCHEMA))
    return topics


def info_document(run_id: str, process: str, topics: list[TopicInfo], source: str = "run") -> bytes:
    from engine.messages.schemas import descriptor_set

    schemas = {t.schema: base64.b64encode(descriptor_set(t.schema)).decode() for t in topics}
    doc = {
        "layout": LAYOUT_VERSION,
        "run_id": run_id,
        "process": process,
        "vgr": __version__,
        "source": source,
        "topics": [asdict(t) for t in topics],
        "schemas": dict(sorted(schemas.items())),
    }
    return json.dumps(doc, separators=(",", ":")).encode()


def announce(bus: Bus, run_id: str, process: str, topics: list[TopicInfo], source: str = "run") -> None:
    """Declare the ``_info`` queryable of this process on *bus* (undeclared when the bus closes)."""
    bus.answer(info_key(run_id, process), info_document(run_id, process, topics, source))


def find_runs(bus: Bus, timeout_s: float = 1.0, run_id: str | None = None) -> dict[str, list[dict[str, Any]]]:
    """Info documents of every process reachable from *bus* (or of run *run_id* only: a secured
    run lets an observer ask its own key, not every run's), by run id (replies that are not a
    document of this layout are skipped)."""
    runs: dict[str, list[dict[str, Any]]] = {}
    key = ALL_INFO if run_id is None else info_key(run_id, "*")
    for reply in bus.session.get(key, timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            doc = json.loads(reply.ok.payload.to_bytes())
        except ValueError:
            continue
        if not isinstance(doc, dict) or doc.get("layout") != LAYOUT_VERSION or "run_id" not in doc:
            continue
        runs.setdefault(str(doc["run_id"]), []).append(doc)
    return runs
