"""Benchmark: the camera model-gap workflow (``vgr gap --camera``) with each camera effect hidden,
on effect-free controls, and on the real kuka_2 images.

Simulated cases (:mod:`plugins.sim.model_gap.camera_views`: a 1280 x 960 camera, f = 700 px, Brown
k1 = -0.3, k2 = 0.1, a 12 x 9-square chessboard seen from 20 random poses, 0.1 px corner noise per
coordinate; detected-corner level): every catalog effect hidden alone at two magnitudes (the
simulator's coefficients x1, "low", and x4, "high"; ``board_shape`` a board bowed by 0.5 / 1 mm), N
trials each with fixed seeds, and effect-free controls. The workflow runs at its defaults (the full
catalog, alpha 1e-3, 5 folds). Reported per effect and magnitude: named exactly / exact or tied (a
tie term containing the hidden effect, nothing else named) / a wrong effect named / verdicts, and
the held-out reprojection RMS before and after against the noise floor ``0.1 sqrt(2)`` px. False
positives: the share of effect-free controls with any term added, at alpha 1e-3 and again at
alpha 0.05, where the rate is measurable (the nominal rate bounds it: the test is conservative).

Real data: the 28 kuka_2 images (/work/shared/data/rwhe_kuka2; 25 x 18 squares of 15 mm): what is
named or tied, the verdict and the held-out RMS before and after.

Run: ``PYTHONPATH=. python benchmarks/camera_gap.py [--trials N] [--controls N] [--jobs 2] [--quick]``
-> benchmarks/results/camera_gap.json
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_results import machine, write_result
from plugins.model_gap.camera.catalog import CATALOG
from plugins.model_gap.camera.workflow import CameraGapConfig, run_camera_gap
from plugins.sim.model_gap.camera_views import simulate_detections

NOISE_PX = 0.1
FLOOR_PX = NOISE_PX * np.sqrt(2.0)
SEED0 = 20261204
MAGNITUDES = {"low": (1.0, 0.5e-3), "high": (4.0, 1.0e-3)}  # (scale of the lens coefficients, board bow m)
KUKA = Path("/work/shared/data/rwhe_kuka2")


def run_case(job: tuple[str | None, str, int, float]) -> dict[str, Any]:
    """One simulated case: hidden *effect* (None: a control) at *magnitude*, trial seed, alpha."""
    effect, magnitude, seed, alpha = job
    scale, bow = MAGNITUDES[magnitude]
    lens = effect if effect not in (None, "board_shape") else None
    views, size = simulate_detections(
        lens, scale=scale, seed=seed, noise_px=NOISE_PX, board_bow_m=bow if effect == "board_shape" else 0.0
    )
    t0 = time.perf_counter()
    r = run_camera_gap(views, size, CameraGapConfig(alpha=alpha, seed=seed))
    wall = time.perf_counter() - t0
    named = r.named
    tied = [sorted([a.effect.name, *(e.name for e in a.tied_with)]) for a in r.added if a.tied_with]
    exact = effect is not None and named == [effect]
    in_tie = effect is not None and not named and any(effect in t for t in tied)
    return {
        "effect": effect,
        "magnitude": magnitude,
        "seed": seed,
        "alpha": alpha,
        "verdict": r.verdict,
        "named": named,
        "tied": tied,
        "parsimony_over": [[e.name for e in a.parsimony_over] for a in r.added],
        "exact": exact,
        "exact_or_tied": exact or in_tie,
        "wrong_name": any(n != effect for n in named),
        "added_any": bool(r.added),
        "heldout_before_px": r.baseline_cv.rms_px,
        "heldout_after_px": r.final_cv.rms_px,
        "after_over_floor": r.final_cv.rms_px / FLOOR_PX,
        "structure_after_p": r.structure_after.p_value,
        "wall_s": wall,
    }


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    verdicts: dict[str, int] = {}
    for r in rows:
        verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
    before = np.array([r["heldout_before_px"] for r in rows])
    after = np.array([r["heldout_after_px"] for r in rows])
    return {
        "n": n,
        "exact": sum(r["exact"] for r in rows),
        "exact_or_tied": sum(r["exact_or_tied"] for r in rows),
        "wrong_name": sum(r["wrong_name"] for r in rows),
        "added_any": sum(r["added_any"] for r in rows),
        "verdicts": verdicts,
        "heldout_before_px_median": float(np.median(before)),
        "heldout_after_px_median": float(np.median(after)),
        "after_over_floor_median": float(np.median(after / FLOOR_PX)),
        "after_over_floor_max": float(np.max(after / FLOOR_PX)),
        "wall_s_median": float(np.median([r["wall_s"] for r in rows])),
    }


def kuka() -> dict[str, Any]:
    """The 28 kuka_2 images at the defaults: detection, the workflow, what is named."""
    from plugins.model_gap.camera.inputs import load_views

    t0 = time.perf_counter()
    dets = load_views([str(KUKA)], "chessboard:25x18:15mm")
    assert dets.image_size is not None
    r = run_camera_gap(dets.found, dets.image_size)
    return {
        "views": len(dets.found),
        "verdict": r.verdict,
        "reason": r.reason,
        "named": r.named,
        "added": [{"term": a.label, "tied": bool(a.tied_with), "fitted_as": a.effect.name} for a in r.added],
        "heldout_before_px": r.baseline_cv.rms_px,
        "heldout_after_px": r.final_cv.rms_px,
        "rms_before_px": r.baseline_fit.rms_px,
        "rms_after_px": r.final_fit.rms_px,
        "rounds": [
            {
                "iteration": rd.iteration,
                "candidates": {
                    s.effect.name: {
                        "heldout_px": s.heldout_rms_px,
                        "p_corrected": s.p_corrected,
                        "eligible": s.eligible,
                    }
                    for s in rd.scores
                },
                "decision": rd.decision.reason,
            }
            for rd in r.rounds
        ],
        "structure_after_p": r.structure_after.p_value,
        "structure_after": r.structure_after.describe(),
        "wall_s": time.perf_counter() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per effect and magnitude (10)")
    ap.add_argument("--controls", type=int, default=40, help="effect-free controls at alpha 1e-3 (40)")
    ap.add_argument("--controls-loose", type=int, default=60, help="effect-free controls at alpha 0.05 (60)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="2 trials, 4 + 10 controls (not the benchmark)")
    ap.add_argument("--no-kuka", action="store_true")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "camera_gap.json"))
    args = ap.parse_args()
    if args.quick:
        args.trials, args.controls, args.controls_loose = 2, 4, 10
    jobs: list[tuple[str | None, str, int, float]] = [
        (e.name, mag, SEED0 + 1000 * k + t, 1e-3)
        for k, e in enumerate(CATALOG)
        for mag in MAGNITUDES
        for t in range(args.trials)
    ]
    jobs += [(None, "low", SEED0 + 100_000 + t, 1e-3) for t in range(args.controls)]
    jobs += [(None, "low", SEED0 + 200_000 + t, 0.05) for t in range(args.controls_loose)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as ex:
        rows = list(ex.map(run_case, jobs))
    per_effect = {
        f"{e.name}/{mag}": _summary([r for r in rows if r["effect"] == e.name and r["magnitude"] == mag])
        for e in CATALOG
        for mag in MAGNITUDES
    }
    controls = {
        str(alpha): _summary([r for r in rows if r["effect"] is None and r["alpha"] == alpha]) for alpha in (1e-3, 0.05)
    }
    result = {
        "benchmark": "camera_gap",
        "machine": machine(),
        "setup": {"noise_px": NOISE_PX, "floor_px": FLOOR_PX, "views": 20, "magnitudes": MAGNITUDES, "seed0": SEED0},
        "per_effect": per_effect,
        "controls": controls,
        "kuka_2": None if args.no_kuka or not KUKA.is_dir() else kuka(),
        "wall_s": time.perf_counter() - t0,
        "cases": rows,
    }
    write_result(Path(args.out), result)
    for key, s in per_effect.items():
        print(
            f"{key:22s} exact {s['exact']}/{s['n']}  exact-or-tied {s['exact_or_tied']}/{s['n']}  wrong {s['wrong_name']}  "
            f"held-out {s['heldout_before_px_median']:.4f} -> {s['heldout_after_px_median']:.4f} px "
            f"(max after/floor {s['after_over_floor_max']:.3f})"
        )
    for alpha, s in controls.items():
        print(f"controls alpha {alpha}: any term added {s['added_any']}/{s['n']}  verdicts {s['verdicts']}")
    if result["kuka_2"]:
        k = result["kuka_2"]
        print(
            f"kuka_2: {k['verdict']}, named {k['named']}, added {[a['term'] for a in k['added']]}, held-out "
            f"{k['heldout_before_px']:.4f} -> {k['heldout_after_px']:.4f} px"
        )


if __name__ == "__main__":
    main()
