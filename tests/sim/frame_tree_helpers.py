"""Record a run and read the frame tree its recording shows in a 3D view, and every frame id its
messages name.

The tree is made of every transform the recording holds, on any port (``frames``, a calibration's
``transform``, ``truth/...``) and in service replies: FrameTransforms and Transform messages, as a 3D
view (Foxglove) reads them all. Every message (streams and service requests/replies) that names a
frame counts: its ``frame_id``, a transform's parent and child, a scene mesh's frame.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from recipe_helpers import graph_from

from engine.graph import Graph
from engine.messages import FrameTransforms, Message, SceneMeshes, Transform, codec
from engine.plugin_manager import load_registry
from engine.recording.reader import load
from engine.recording.recorder import Recorder
from engine.run.runner import Runner, RunSummary

ROOT = "world"
ROBOT_FRAMES = {"base": "world", "tcp": "base"}  # child -> parent: what a robot stage (simulated or UR) publishes


@dataclass
class FrameTree:
    parents: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))  # child -> parents
    named_by: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))  # frame -> topics
    edges_by: dict[tuple[str, str], set[str]] = field(default_factory=lambda: defaultdict(set))

    def path_to_root(self, frame: str) -> list[str]:
        """``frame``, its parent, ... up to the root, or up to where the chain breaks."""
        chain = [frame]
        while chain[-1] != ROOT and len(self.parents.get(chain[-1], ())) == 1 and len(chain) < 64:
            (parent,) = self.parents[chain[-1]]
            if parent in chain:
                break
            chain.append(parent)
        return chain

    def parent_of(self) -> dict[str, str]:
        """Each frame's parent (the first, where a frame has several: see :meth:`problems`)."""
        return {child: next(iter(p)) for child, p in self.parents.items()}

    def problems(self) -> list[str]:
        """What keeps the published frames from being one tree rooted at ``world``."""
        out = []
        for child, parents in sorted(self.parents.items()):
            if len(parents) > 1:
                out.append(f"frame {child!r} has {len(parents)} parents {sorted(parents)}")
        for frame, topics in sorted(self.named_by.items()):
            chain = self.path_to_root(frame)
            if chain[-1] != ROOT:
                out.append(f"frame {frame!r} (named on {sorted(topics)}) does not reach {ROOT!r}: {' -> '.join(chain)}")
        return out


def _names(msg: Message) -> tuple[list[str], list[tuple[str, str]]]:
    transforms: list[Transform] = []
    if isinstance(msg, FrameTransforms):
        transforms = list(msg.transforms)
    elif isinstance(msg, Transform):
        transforms = [msg]
    names = [msg.frame_id] if getattr(msg, "frame_id", "") else []
    if isinstance(msg, SceneMeshes):
        names += [m.frame_id for m in msg.meshes]
    edges = [(t.frame_id, t.child_frame_id) for t in transforms]
    return names + [f for e in edges for f in e], edges


def frame_tree(path: str | Path) -> FrameTree:
    tree = FrameTree()
    rec = load(path)
    load_registry()  # the stages' own message types (e.g. MatchResult) register with their plugins
    for r in rec.records:
        if r[0] == "msg":
            m = r[1]
            msgs = [(m.topic, codec.decode_payload(codec.registry.get(m.type_name), m.payload))]
        elif r[0] == "svc":
            ex, topic = r[1], f"/{r[1].provider}/srv/{r[1].service}"
            msgs = [(topic, codec.decode_payload(codec.registry.get(ex.request_type), ex.request))]
            if not ex.error:
                msgs.append((topic, codec.decode_payload(codec.registry.get(ex.reply_type), ex.reply)))
        else:
            continue
        for topic, msg in msgs:
            names, edges = _names(msg)
            for name in names:
                tree.named_by[name].add(topic)
            for parent, child in edges:
                tree.parents[child].add(parent)
                tree.edges_by[(parent, child)].add(topic)
    return tree


def sound_frame_tree(path: str | Path) -> FrameTree:
    """:func:`frame_tree` of a recording that must form one tree under ``world``."""
    tree = frame_tree(path)
    assert not tree.problems(), "\n".join(tree.problems())
    return tree


def record(text: str, path: Path, plugins: list[str]) -> Path:
    """Run the recipe *text* recorded to *path* (*plugins*: the plugin modules the recording lists);
    the run must end well."""
    record_graph(graph_from(text), path, plugins)
    return path


def record_graph(graph: Graph, path: Path, plugins: list[str]) -> RunSummary:
    """Run *graph* recorded to *path*; the run must end well."""
    summary = Runner(graph, observers=[Recorder(path, graph.recipe.record, graph.loaded, plugins)]).run()
    assert summary.ok, summary.stop_reason
    return summary
