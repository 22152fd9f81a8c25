"""How a run's cost grows with its number of stages: run time, threads and end-of-run checks for
25 to 1000 stages, in one process, as a chain and as a fan-out.

* **chain**: ``bench_source`` -> ``bench_relay`` x (N-2) -> ``bench_tally``: every message crosses
  every stage in turn;
* **fan-out**: ``bench_source`` -> ``bench_tally`` x (N-1): one port with N-1 consumers.

The source sends ``--messages`` Blobs of 64 bytes as fast as it can (benchmarks/bench_stages.py).
Per configuration, ``--repeats`` runs (the two topologies alternate, sizes in turn), each one
``engine.run.runner.Runner.run()`` in this process on a graph built before the clock starts:
``wall_s`` is the run's own time (RunSummary.wall_s: barrier, set-up, data, end, shutdown),
``build_s`` the graph's construction (recipe text to Graph), ``threads_peak`` the most threads
alive while it ran (sampled every 5 ms), ``done_checks`` how often the runner evaluated the end of
the run (Runner.done_checks). The medians are reported, with ``wall_per_stage_ms``.

Targets (PASS/FAIL, in the JSON), each topology: run time linear in the stages, i.e.
``wall_per_stage_ms`` at the largest size at most 1.5x the one at 100 stages; end-of-run checks
linear too (``done_checks`` per stage at most 1.5x the one at 25 stages); threads at most 1.5 per
stage (a local input has a thread only once a message waits for it: here, nearly none).

Usage: ``python benchmarks/stage_scaling.py`` (sizes 25, 50, 100, 200, 400, 1000; 3 repeats) or
``--quick`` (25, 50, 100, 200; 1 repeat; writes ``stage_scaling_quick.json``).
"""

from __future__ import annotations

import argparse
import gc
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(ROOT), str(HERE)]

from bench_results import machine, write_result  # noqa: E402

from engine.graph import build_graph  # noqa: E402
from engine.plugin_manager import load_registry  # noqa: E402
from engine.recipe.model import load_recipe  # noqa: E402
from engine.run.runner import Runner  # noqa: E402

SIZES = (25, 50, 100, 200, 400, 1000)
QUICK_SIZES = (25, 50, 100, 200)
TOPOLOGIES = ("chain", "fanout")
LINEAR_FACTOR = 1.5  # per-stage time (or checks) at the largest size vs at a small one
MAX_THREADS_PER_STAGE = 1.5


def recipe_text(topology: str, n: int, messages: int, run_id: str) -> str:
    lines = [
        f"name: scale_{topology}_{n}",
        "plugins: [bench_stages]",
        f"run_id: {run_id}",
        "record: {enabled: false}",
        "stages:",
        f"  src: {{type: bench_source, params: {{count: {messages}, warmup: 0, size: 64}}}}",
    ]
    if topology == "chain":
        prev = "src"
        for i in range(n - 2):
            lines.append(f"  r{i}: {{type: bench_relay, inputs: {{in: {prev}.out}}}}")
            prev = f"r{i}"
        lines.append(f"  sink: {{type: bench_tally, inputs: {{in: {prev}.out}}}}")
    else:
        lines += [f"  t{i}: {{type: bench_tally, inputs: {{in: src.out}}}}" for i in range(n - 1)]
    return "\n".join(lines) + "\n"


def one_run(topology: str, n: int, messages: int, k: int) -> dict[str, Any]:
    """Build and run one configuration; its figures."""
    text = recipe_text(topology, n, messages, f"scale_{topology}_{n}_{k}")
    t0 = time.perf_counter()
    loaded = load_recipe(HERE / "stage_scaling.yaml", text=text)  # (bench_stages.py is found next to it)
    graph = build_graph(loaded, load_registry(loaded.recipe.plugins))
    build_s = time.perf_counter() - t0
    runner = Runner(graph)
    peak, done = [threading.active_count()], threading.Event()

    def sample() -> None:
        while not done.wait(0.005):
            peak[0] = max(peak[0], threading.active_count())

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    summary = runner.run()
    done.set()
    sampler.join()
    assert summary.ok, summary.stop_reason
    return {
        "wall_s": summary.wall_s,
        "build_s": build_s,
        "threads_peak": peak[0] - 1,  # (less the sampler)
        "done_checks": runner.done_checks,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="sizes up to 200, one repeat, *_quick.json")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--messages", type=int, default=20)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    sizes = QUICK_SIZES if args.quick else SIZES
    repeats = 1 if args.quick else args.repeats
    runs: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for k in range(repeats):
        for n in sizes:
            for topology in TOPOLOGIES if k % 2 == 0 else TOPOLOGIES[::-1]:
                gc.collect()
                r = one_run(topology, n, args.messages, k)
                runs.setdefault((topology, n), []).append(r)
                print(f"{topology:6s} {n:5d} stages: run {r['wall_s']:.2f} s, build {r['build_s']:.2f} s, "
                      f"threads {r['threads_peak']}, end checks {r['done_checks']}", flush=True)  # fmt: skip
    configs, targets = [], {}
    for topology in TOPOLOGIES:
        rows = []
        for n in sizes:
            rs = runs[(topology, n)]
            wall = statistics.median(r["wall_s"] for r in rs)
            rows.append(
                {
                    "topology": topology,
                    "stages": n,
                    "wall_s": wall,
                    "wall_per_stage_ms": 1e3 * wall / n,
                    "build_s": statistics.median(r["build_s"] for r in rs),
                    "threads_peak": max(r["threads_peak"] for r in rs),
                    "done_checks": max(r["done_checks"] for r in rs),
                    "runs": rs,
                }
            )
        configs += rows
        at100 = next(r for r in rows if r["stages"] == 100)["wall_per_stage_ms"]
        largest = rows[-1]
        factor = largest["wall_per_stage_ms"] / at100
        targets[f"{topology}_linear"] = {
            "per_stage_ms_at_100": at100,
            f"per_stage_ms_at_{largest['stages']}": largest["wall_per_stage_ms"],
            "factor": factor,
            "limit": LINEAR_FACTOR,
            "pass": factor <= LINEAR_FACTOR,
        }
        checks = [r["done_checks"] / r["stages"] for r in rows]
        targets[f"{topology}_done_checks_linear"] = {
            "per_stage_at_25": checks[0],
            f"per_stage_at_{largest['stages']}": checks[-1],
            "factor": checks[-1] / checks[0],
            "limit": LINEAR_FACTOR,
            "pass": checks[-1] / checks[0] <= LINEAR_FACTOR,
        }
        threads = max(r["threads_peak"] / r["stages"] for r in rows)
        targets[f"{topology}_threads"] = {
            "max_per_stage": threads,
            "limit": MAX_THREADS_PER_STAGE,
            "pass": threads <= MAX_THREADS_PER_STAGE,
        }
    out = args.out or HERE / "results" / ("stage_scaling_quick.json" if args.quick else "stage_scaling.json")
    write_result(
        out,
        {
            "benchmark": "stage_scaling",
            "machine": machine(),
            "messages": args.messages,
            "repeats": repeats,
            "configs": configs,
            "targets": targets,
        },
    )
    for name, t in targets.items():
        print(f"{name}: {'PASS' if t['pass'] else 'FAIL'} {t}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
