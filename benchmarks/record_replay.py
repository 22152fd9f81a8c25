"""Recording and replay costs, measured in one run.

1. Recording overhead: frames per second of a point-cloud pipeline (synthetic_cloud -> transform_cloud
   -> cloud_stats, 50k points per cloud, as fast as it goes, in one process) with recording off and
   on (zstd, lz4). After one uncounted warm-up run, the variants alternate run by run, so load
   drifting over time hits each alike; medians over the repeats. Target: on/off >= 0.9.
   The same comparison is made on whole runs of shipped recipes (recipes/eye_in_hand_dock.yaml,
   planar_assembly.yaml: the simulated cell on the simulated clock, so compute-bound), whose
   recordings hold the captured clouds of every look with the rest of the run.
2. Replay speed: a 30 Hz stream (5k and 50k points per cloud) recorded on the simulated clock, then
   ``vgr replay`` with ``--speed max`` (the default), which re-runs transform_cloud and cloud_stats on
   the recorded clouds and diffs every output. Speed = recorded span / replay wall time (the replay
   includes loading and indexing the file). Target: >= 50x real time. A replay cannot be faster than
   the re-run stages' own work (here cloud_stats' float64 statistics dominate at 50k points), so the
   time inside their handlers is reported too, and ``engine_speed_x_real_time`` = recorded span /
   (wall - that time): what the replay machinery itself (reading, decompressing, decoding, feeding,
   encoding and diffing the outputs) allows.
3. File size per minute of one 30 Hz 50k-point stream (synthetic_cloud -> cloud_stats, so the file
   holds that one cloud stream plus the small stats and delivery records), by compression, against
   the raw payload rate (50k x 12 B x 30 Hz = 1080 MB/min). The synthetic clouds are noisy float32 box
   surfaces: close to incompressible, so this is an upper bound for depth-camera clouds.

All recordings go to one temporary folder, each deleted as soon as it is measured (the folder at the
end): a full run writes several GB in total but holds at most ~1.1 GB at a time.

Usage: ``python benchmarks/record_replay.py [--quick] [--out FILE]``; writes
benchmarks/results/record_replay.json (``--quick``: record_replay_quick.json, git-ignored).
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
from engine.recipe.model import LoadedRecipe, load_recipe  # noqa: E402
from engine.recording.recorder import Recorder  # noqa: E402
from engine.recording.replay import _ReplayContext, replay  # noqa: E402
from engine.run.runner import Runner  # noqa: E402

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
STREAM = """
name: rec_size
seed: 1
clock: sim
record: {{compression: {compression}}}
stages:
  source: {{type: synthetic_cloud, params: {{n_points: {n}, frames: {frames}, rate_hz: {rate}, noise_m: 0.0005}}}}
  stats: {{type: cloud_stats, inputs: {{cloud: source.cloud}}}}
"""
REGISTRY = load_registry()


def run_loaded(loaded: LoadedRecipe, record: Path | None) -> tuple[float, float]:
    """Run *loaded* in this process, recording to *record* unless None: (wall seconds, process CPU
    seconds: every thread, the recorder's included)."""
    graph = build_graph(loaded, REGISTRY)
    observers = [Recorder(record, graph.recipe.record, loaded, REGISTRY.plugins)] if record else []
    t0, c0 = time.perf_counter(), time.process_time()
    summary = Runner(graph, observers=observers).run()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    assert summary.ok, summary.stop_reason
    assert "recording_error" not in summary.artifacts, summary.artifacts
    return wall, cpu


def run(text: str, frames: int, record: Path | None) -> tuple[float, float]:
    """Run the recipe *text* (recording to *record* unless None): (frames per second of wall time,
    process CPU ms per frame: every thread, the recorder's included)."""
    wall, cpu = run_loaded(load_recipe("rec_bench.yaml", text=text), record)
    return frames / wall, cpu / frames * 1e3


class HandlerTimer:
    """Times the re-run stages' handlers during a replay (minus the engine's publish inside them)."""

    def __init__(self, type_names: list[str]) -> None:
        self.classes = [REGISTRY.stage(t) for t in type_names]
        self.stage_s = 0.0
        self.depth = 0

    def __enter__(self) -> HandlerTimer:
        self.saved = [(c, c.on_message) for c in self.classes]
        self.saved_publish = _ReplayContext.publish
        timer = self

        def wrap(fn):  # type: ignore[no-untyped-def]
            def on_message(stage, port, msg):  # type: ignore[no-untyped-def]
                t0 = time.perf_counter()
                try:
                    return fn(stage, port, msg)
                finally:
                    timer.stage_s += time.perf_counter() - t0

            return on_message

        def publish(ctx, port, msg):  # type: ignore[no-untyped-def]
            t0 = time.perf_counter()
            try:
                return timer.saved_publish(ctx, port, msg)
            finally:
                timer.stage_s -= time.perf_counter() - t0

        for c, fn in self.saved:
            c.on_message = wrap(fn)
        _ReplayContext.publish = publish
        return self

    def __exit__(self, *exc: object) -> None:
        for c, fn in self.saved:
            c.on_message = fn
        _ReplayContext.publish = self.saved_publish


SHIPPED = ("eye_in_hand_dock", "planar_assembly")  # recipes whose run the recording overhead is also measured on


def run_recipe(name: str, record: Path | None) -> float:
    """Wall seconds of one run of recipes/<name>.yaml in this process, recording to *record* unless None."""
    return run_loaded(load_recipe(str(HERE.parent / "recipes" / f"{name}.yaml")), record)[0]


def recipe_overhead(tmp: Path, repeat: int) -> dict[str, object]:
    """Recording on (the recipe's own settings: zstd) vs off for whole runs of shipped recipes: the
    simulated cell renders, matches and moves on the simulated clock, so a run is compute-bound and
    its wall time is what recording slows down. One uncounted warm-up run each, then off/on alternate."""
    rows: dict[str, object] = {}
    for name in SHIPPED:
        run_recipe(name, None)
        walls: dict[str, list[float]] = {"off": [], "on": []}
        size = 0.0
        for _ in range(repeat):
            walls["off"].append(run_recipe(name, None))
            path = tmp / f"recipe_{name}.mcap"
            walls["on"].append(run_recipe(name, path))
            size = path.stat().st_size / 1e6
            path.unlink()
        med = {k: statistics.median(v) for k, v in walls.items()}
        rows[name] = {
            "wall_s_median": med,
            "wall_s_runs": walls,
            "recording_MB": size,
            "ratio_on_over_off": med["off"] / med["on"],  # runs per second, on / off
        }
        print(
            f"recording overhead, recipes/{name}.yaml: off {med['off']:.2f} s, on {med['on']:.2f} s "
            f"({size:.1f} MB): ratio {med['off'] / med['on']:.3f}",
            flush=True,
        )
    return {"target": ">= 0.9", **rows}


def pipeline(n: int, frames: int, rate: float, clock: str, compression: str = "zstd") -> str:
    return PIPELINE.format(n=n, frames=frames, rate=rate, clock=clock, compression=compression)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer frames and repeats (smoke test)")
    ap.add_argument("--out", type=Path, help="result file (default benchmarks/results/record_replay[_quick].json)")
    args = ap.parse_args()
    t_start = time.monotonic()
    repeat = 1 if args.quick else 5
    frames = 40 if args.quick else 200
    results: dict[str, object] = {}
    with tempfile.TemporaryDirectory(prefix="vgr-bench-record-") as tmp_dir:
        tmp = Path(tmp_dir)

        # 1. recording overhead: same pipeline, variants interleaved run by run, after one run that is
        # not counted (the first run in a process is ~30 % slower: imports, caches, allocator growth,
        # and it would always be an "off" run)
        run(pipeline(50_000, frames, 0.0, "sim"), frames, None)
        rates: dict[str, list[float]] = {"off": [], "zstd": [], "lz4": []}
        cpus: dict[str, list[float]] = {k: [] for k in rates}
        for _ in range(repeat):
            for variant in rates:
                comp = "zstd" if variant == "off" else variant
                path = None if variant == "off" else tmp / f"overhead_{variant}.mcap"
                rate, cpu = run(pipeline(50_000, frames, 0.0, "sim", comp), frames, path)
                rates[variant].append(rate)
                cpus[variant].append(cpu)
                if path is not None:
                    path.unlink()
        med = {k: statistics.median(v) for k, v in rates.items()}
        cpu_med = {k: statistics.median(v) for k, v in cpus.items()}
        results["recording_overhead"] = {
            "pipeline": "synthetic_cloud(50k pts) -> transform_cloud -> cloud_stats, max rate, in-process",
            "frames_per_run": frames,
            "repeat": repeat,
            "frames_per_s_median": med,
            "frames_per_s_runs": rates,
            "ratio_on_over_off": {k: med[k] / med["off"] for k in ("zstd", "lz4")},
            "cpu_ms_per_frame_median": cpu_med,
            # the ratio a run bound by CPU would show (steadier than wall-clock rates on a shared machine)
            "ratio_on_over_off_cpu": {k: cpu_med["off"] / cpu_med[k] for k in ("zstd", "lz4")},
            # what recording this pipeline costs at a camera's rate instead of flat out: the extra CPU
            # per frame x 30 frames per second, as a share of one core
            "recording_core_share_at_30Hz": {k: (cpu_med[k] - cpu_med["off"]) * 30 / 1000 for k in ("zstd", "lz4")},
            "target": ">= 0.9",
        }
        print(
            "recording overhead (frames/s):",
            {k: round(v, 1) for k, v in med.items()},
            "ratio zstd {:.2f} lz4 {:.2f}".format(med["zstd"] / med["off"], med["lz4"] / med["off"]),
            "| CPU ms/frame",
            {k: round(v, 2) for k, v in cpu_med.items()},
            "| recording at 30 Hz: {:.1%} of a core (zstd)".format((cpu_med["zstd"] - cpu_med["off"]) * 30 / 1000),
            flush=True,
        )

        # 1b. the same comparison on shipped recipes (simulated cell, simulated clock: compute-bound)
        results["recording_overhead_recipes"] = recipe_overhead(tmp, repeat)

        # 2. replay speed of 30 Hz recordings (--speed max)
        seconds = 10 if args.quick else 60
        replay_rows = {}
        for n in (5_000, 50_000):
            rec = tmp / f"sensor_{n}.mcap"
            run(pipeline(n, 30 * seconds, 30.0, "sim"), 30 * seconds, rec)
            walls, stage_s = [], []
            for _ in range(1 if args.quick else 5):  # single replays of 1-2 s vary by +-15 %
                with HandlerTimer(["transform_cloud", "cloud_stats"]) as timer:
                    t0 = time.perf_counter()
                    report, _, _ = replay(rec)
                    walls.append(time.perf_counter() - t0)
                stage_s.append(timer.stage_s)
                assert report.ok and report.rerun, report
            wall, in_stages = statistics.median(walls), statistics.median(stage_s)
            replay_rows[f"{n // 1000}k_points"] = {
                "recording": f"30 Hz, {n} points per cloud, {seconds} s on the simulated clock",
                "file_MB": rec.stat().st_size / 1e6,
                "rerun": report.rerun,
                "replay_wall_s_median": wall,
                "in_rerun_stage_handlers_s_median": in_stages,
                "speed_x_real_time": seconds / wall,
                "engine_speed_x_real_time": seconds / max(wall - in_stages, 1e-9),
            }
            rec.unlink()
            print(
                f"replay: {seconds} s of 30 Hz {n}-point clouds in {wall:.2f} s = {seconds / wall:.0f}x real time "
                f"({in_stages:.2f} s in the re-run stages; engine alone {seconds / (wall - in_stages):.0f}x)",
                flush=True,
            )
        results["replay_speed"] = {"speed": "max", "target": ">= 50x", **replay_rows}

        # 3. file size per minute of one 30 Hz 50k-point stream
        seconds = 5 if args.quick else 60
        sizes = {}
        for comp in ("zstd", "lz4", "none"):
            path = tmp / f"size_{comp}.mcap"
            text = STREAM.format(n=50_000, frames=30 * seconds, rate=30.0, compression=comp)
            run(text, 30 * seconds, path)
            sizes[comp] = path.stat().st_size / 1e6 * 60 / seconds
            path.unlink()
        results["file_size"] = {
            "stream": "one 30 Hz stream of 50k-point float32 clouds (600 kB per frame), plus its stats",
            "seconds_recorded": seconds,
            "MB_per_minute": sizes,
            "raw_payload_MB_per_minute": 30 * 60 * 50_000 * 12 / 1e6,
        }
        print("MB per minute:", {k: round(v, 1) for k, v in sizes.items()}, flush=True)

    elapsed = time.monotonic() - t_start
    out = args.out or HERE / "results" / ("record_replay_quick.json" if args.quick else "record_replay.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {
        "benchmark": "record_replay",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "method": __doc__,
        **results,
        "duration_s": round(elapsed, 1),
    }
    out.write_text(json.dumps(doc, indent=2))
    print(f"written {out} after {elapsed:.0f} s")


if __name__ == "__main__":
    main()
