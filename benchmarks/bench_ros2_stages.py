"""The stage benchmarks/ros2_bridge.py measures vgr with (loaded through a recipe's ``plugins:`` list).

``bench_cloud_sink`` takes the clouds ``ros2_subscribe`` converts and records, at the entry of its
handler, the one-way latency from the publisher's header stamp (``time.time_ns()`` just before the
publish: one clock for every process on the machine) and the arrival time; it writes them as JSON
when the stream ends.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import ClassVar

from engine.hookspecs import hookimpl
from engine.messages import PointCloud
from engine.stage import Stage, StageParams


class BenchCloudSink(Stage):
    """Latency (ns, from the header stamp) and arrival time of every cloud; JSON on finish."""

    type_name = "bench_cloud_sink"
    role = "sink"
    inputs: ClassVar = {"in": PointCloud}

    class Params(StageParams):
        output: str = "bench_cloud_sink.json"

    def setup(self) -> None:
        self.lat: list[int] = []
        self.arrivals: list[int] = []
        self.points = 0

    def on_message(self, port: str, msg: PointCloud) -> None:  # type: ignore[override]
        now = time.time_ns()
        self.lat.append(now - msg.stamp_ns)
        self.arrivals.append(now)
        self.points = len(msg.points)

    def finish(self) -> None:
        out = {"lat_ns": self.lat, "arrivals_ns": self.arrivals, "points": self.points}
        Path(self.params.output).write_text(json.dumps(out))  # type: ignore[attr-defined]


@hookimpl
def vgr_stage_types() -> list[type]:
    return [BenchCloudSink]
