"""Recording and replay costs, measured in one run.

1. Recording overhead: messages per second of a point-cloud pipeline (synthetic_cloud ->
   transform_cloud -> cloud_stats, 50k points per cloud, as fast as it goes) with recording off and
   on (zstd and lz4). Target: on/off >= 0.9.
2. Replay speed: a 30 Hz, 5k-point stream recorded on the simulated clock for 60 s, replayed with
   ``--speed max`` (re-running transform_cloud and cloud_stats and diffing their outputs).
   Target: >= 50x real time.
3. File size per minute of a 30 Hz 50k-point stream (source + transformed copy recorded), by
   compression. The synthetic clouds are noisy float32 box surfaces: close to incompressible,
   so this is an upper bound for organised depth-camera clouds.

Usage: ``python benchmarks/record_replay.py [--quick]``; writes benchmarks/results/record_replay.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent)]

from engine.graph import build_graph  # noqa: E402
from engine.plugin_manager import load_registry  # noqa: E402
from engine.recipe import load_recipe  # noqa: E402
from engine.recorder import Recorder  # noqa: E402
from engine.replay import replay  # noqa: E402
from engine.runner import Runner  # noqa: E402

PIPELINE = """
name: rec_bench
seed: 1
clock: {clock}
record: {{compression: {compression}}}
stages:
  source: {{type: synthetic_cloud, params: {{n_points: {n}, frames: {frames}, rate_hz: {rate}, noise_m: 0.0005}}}}
  move: {{type: transform_cloud, inputs: {{cloud: source.cloud}}, params: {{translation_m: [0.01, 0, 0.5], rotation_deg: [0, 0, 10]}}}}
  stats: {{type: cloud_stats, inputs: {{cloud: move.cloud}}}}
"""
REGISTRY = load_registry()


def run(
    n: int, frames: int, rate: float, clock: str, record: Path | None, compression: str = "zstd"
) -> tuple[float, float]:
    """(wall seconds of the run, messages per second through the sink)."""
    text = PIPELINE.format(n=n, frames=frames, rate=rate, clock=clock, compression=compression)
    loaded = load_recipe("rec_bench.yaml", text=text)
    graph = build_graph(loaded, REGISTRY)
    observers = [Recorder(record, graph.recipe.record, loaded, REGISTRY.plugins)] if record else []
    t0 = time.perf_counter()
    summary = Runner(graph, observers=observers).run()
    wall = time.perf_counter() - t0
    assert summary.ok, summary.stop_reason
    return wall, frames / wall


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    repeat = 1 if args.quick else 5
    frames = 40 if args.quick else 200
    tmp = Path(tempfile.mkdtemp())
    results: dict[str, object] = {}

    # 1. recording overhead (same pipeline, interleaved runs so load drifts hit every variant alike)
    rates: dict[str, list[float]] = {"off": [], "zstd": [], "lz4": []}
    for i in range(repeat):
        rates["off"].append(run(50_000, frames, 0.0, "sim", None)[1])
        rates["zstd"].append(run(50_000, frames, 0.0, "sim", tmp / f"o{i}.mcap", "zstd")[1])
        rates["lz4"].append(run(50_000, frames, 0.0, "sim", tmp / f"l{i}.mcap", "lz4")[1])
    med = {k: statistics.median(v) for k, v in rates.items()}
    results["recording_overhead"] = {
        "pipeline": "synthetic_cloud(50k pts) -> transform_cloud -> cloud_stats, max rate, in-process",
        "frames_per_run": frames,
        "repeat": repeat,
        "msgs_per_s_median": med,
        "ratio_on_over_off": {k: med[k] / med["off"] for k in ("zstd", "lz4")},
        "target": ">= 0.9",
    }
    print(
        "recording overhead (msg/s):",
        {k: round(v, 1) for k, v in med.items()},
        "ratio zstd {:.2f} lz4 {:.2f}".format(med["zstd"] / med["off"], med["lz4"] / med["off"]),
    )

    # 2. replay speed of a 30 Hz recording
    seconds = 10 if args.quick else 60
    rec = tmp / "sensor.mcap"
    run(5_000, 30 * seconds, 30.0, "sim", rec, "zstd")
    walls = []
    for _ in range(max(1, repeat // 2)):
        t0 = time.perf_counter()
        report, _, _ = replay(rec)
        walls.append(time.perf_counter() - t0)
        assert report.ok
    wall = statistics.median(walls)
    results["replay_speed"] = {
        "recording": f"30 Hz, 5k points, {seconds} s of simulated time",
        "rerun": report.rerun,
        "replay_wall_s_median": wall,
        "speed_x_real_time": seconds / wall,
        "target": ">= 50x",
    }
    print(f"replay: {seconds} s of 30 Hz data replayed in {wall:.2f} s = {seconds / wall:.0f}x real time")

    # 3. file size per minute at 30 Hz, 50k points
    seconds = 10 if args.quick else 60
    sizes = {}
    for comp in ("zstd", "lz4", "none"):
        path = tmp / f"size_{comp}.mcap"
        run(50_000, 30 * seconds, 30.0, "sim", path, comp)
        sizes[comp] = path.stat().st_size / 1e6 * 60 / seconds
    results["file_size"] = {
        "stream": "30 Hz, 50k points float32 (600 kB/frame), recorded twice (source and transformed)",
        "MB_per_minute": sizes,
        "raw_payload_MB_per_minute": 2 * 30 * 60 * 50_000 * 12 / 1e6,
    }
    print("MB per minute:", {k: round(v, 1) for k, v in sizes.items()})

    out = HERE / "results" / ("record_replay_quick.json" if args.quick else "record_replay.json")
    out.parent.mkdir(exist_ok=True)
    out.write_text(
        json.dumps(
            {"benchmark": "record_replay", "date": time.strftime("%Y-%m-%d %H:%M:%S"), "method": __doc__, **results},
            indent=2,
        )
    )
    print(f"written {out}")


if __name__ == "__main__":
    main()
