"""Stages of the shared-memory view tests (tests/engine_core/test_shm_views*.py), loaded through a
recipe's ``plugins: [view_stages]`` with ``VGR_PLUGIN_PATH`` naming this folder.

``t_cloud_source`` publishes ``n`` point clouds of ``points`` points (cloud *i* is
:func:`cloud_points`), ``interval_s`` apart, filled into ``ctx.loan`` arrays with ``loan``. ``t_view_sink`` writes, per cloud, its seq, SHA-256,
whether it arrived as a view of shared memory (:func:`shared_view`) and whether its array is
writeable; it keeps the first ``keep`` clouds as they came (no copy) and checks at the end that
they still hold what they held on arrival (the lifetime rule: a view kept is never overwritten);
``delay_s`` makes it slow. ``t_cloud_shift`` publishes each cloud moved to its centroid.
"""

from __future__ import annotations

import hashlib
import json
import mmap
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from engine.hookspecs import hookimpl
from engine.messages import PointCloud
from engine.stage import Stage, StageParams


def cloud_points(i: int, points: int) -> np.ndarray:
    return np.arange(3 * points, dtype=np.float64).reshape(-1, 3) * 0.001 + i


def shared_view(arr: Any) -> bool:
    """Whether *arr*'s memory is a mapping of shared memory (its chain of bases ends in an mmap)."""
    seen = 0
    while arr is not None and seen < 16:
        if isinstance(arr, mmap.mmap):
            return True
        arr = arr.obj if isinstance(arr, memoryview) else getattr(arr, "base", None)
        seen += 1
    return False


class CloudSource(Stage):
    type_name = "t_cloud_source"
    role = "source"
    outputs: ClassVar = {"cloud": PointCloud}

    class Params(StageParams):
        n: int = 5
        points: int = 50_000
        interval_s: float = 0.0
        loan: bool = False  # fill arrays from ctx.loan (in the port's pool: sent without a copy)
        stats: str = ""  # JSON file for the port's pool figures (loaned_sent, shared)

    def run(self) -> None:
        p = self.params
        for i in range(p.n):
            if p.loan:
                points = self.ctx.loan("cloud", (p.points, 3), np.float64)
                points[:] = cloud_points(i, p.points)
            else:
                points = cloud_points(i, p.points)
            self.ctx.publish("cloud", PointCloud(points=points, frame_id="grid"))
            del points  # (a loaned block comes back once nothing here refers to it)
            if p.interval_s:
                time.sleep(p.interval_s)
        if p.stats:
            views = self.ctx.outputs["cloud"].views  # type: ignore[attr-defined]  # (the runtime's port)
            Path(p.stats).write_text(json.dumps({"loaned_sent": views.loaned_sent, "shared": views.shared}))


class ViewSink(Stage):
    type_name = "t_view_sink"
    role = "sink"
    inputs: ClassVar = {"cloud": PointCloud}

    class Params(StageParams):
        output: str = "views.json"
        keep: int = 0
        delay_s: float = 0.0  # a slow consumer: the sender's pool fills

    def setup(self) -> None:
        self.rows: list[dict[str, Any]] = []
        self.kept: list[tuple[PointCloud, str]] = []

    def on_message(self, port: str, msg: PointCloud) -> None:  # type: ignore[override]
        digest = hashlib.sha256(np.ascontiguousarray(msg.points).tobytes()).hexdigest()
        self.rows.append(
            {
                "seq": msg.seq,
                "sha": digest,
                "view": shared_view(msg.points),
                "writeable": bool(msg.points.flags.writeable),
            }
        )
        if len(self.kept) < self.params.keep:
            self.kept.append((msg, digest))
        if self.params.delay_s:
            time.sleep(self.params.delay_s)

    def finish(self) -> None:
        intact = [hashlib.sha256(m.points.tobytes()).hexdigest() == d for m, d in self.kept]
        Path(self.params.output).write_text(json.dumps({"rows": self.rows, "kept_intact": intact}))


class CloudShift(Stage):
    """Publishes each cloud moved to its centroid (a new array computed from the one received) and
    writes, per cloud, whether it arrived as a view (``output``, JSON list)."""

    type_name = "t_cloud_shift"
    inputs: ClassVar = {"cloud": PointCloud}
    outputs: ClassVar = {"cloud": PointCloud}

    class Params(StageParams):
        output: str = ""

    def setup(self) -> None:
        self.views: list[bool] = []

    def on_message(self, port: str, msg: PointCloud) -> None:  # type: ignore[override]
        self.views.append(shared_view(msg.points))
        self.ctx.publish("cloud", PointCloud(points=msg.points - msg.points.mean(axis=0), frame_id=msg.frame_id))

    def finish(self) -> None:
        if self.params.output:
            Path(self.params.output).write_text(json.dumps(self.views))


@hookimpl
def vgr_stage_types() -> list[type]:
    return [CloudSource, ViewSink, CloudShift]
