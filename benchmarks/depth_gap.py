"""Benchmark: the depth camera's model-gap workflow (``vgr gap --depth``) with each range effect
hidden, with flying pixels, and on effect-free controls.

Simulated captures (:mod:`plugins.sim.model_gap.depth_captures`: an 80 x 60 depth camera with a 60
degree field of view, noise ``sigma(z) = 0.2 mm + 1 mm/m^2 z^2``, 16 captures of a flat plate that
fills the image, 0.4-1.2 m away, tilted up to 35 degrees; the target's true pose known): every catalog
effect hidden alone by the sensor model at three magnitudes (the simulator's ``EFFECT_NOISE`` x0.05,
"trace", x0.2, "faint", and x1, "nominal": about 1-2 mm where the effect acts, against 0.4-1.6 mm of
noise; 80 000 pixels make even a trace of 0.1 mm visible), N trials each with fixed seeds; the same with the plane fitted per capture (no pose:
``--target fit``); the same at the nominal magnitude with 1, 5 and 10 % of the pixels made flying
pixels at known places (moved 2-20 cm along the ray, either sign, as the simulator's
``outlier_fraction`` does); and effect-free controls, clean and with 5 % flying pixels. The workflow runs at its defaults (the full catalog, alpha 1e-3, 5 folds,
the noise estimated). Reported per case: named exactly / exact or tied (a tie term containing the
hidden effect, nothing else named) / a wrong effect named / verdicts; the held-out RMS range error
per pixel before and after (mm) and after over the simulated noise's own RMS (the floor); with flying
pixels how many of them were flagged (recall) and how many good pixels were (false flags). False positives: the share of
effect-free controls with any term added, at alpha 1e-3 and again at alpha 0.05, where a rate is
measurable (the nominal rate bounds it: the held-out test is conservative).

Run: ``PYTHONPATH=. python benchmarks/depth_gap.py [--trials N] [--controls N] [--jobs 2] [--quick]``
-> benchmarks/results/depth_gap.json
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
from plugins.model_gap.depth.catalog import CATALOG
from plugins.model_gap.depth.data import DepthCaptures, DepthFrame, prepare
from plugins.model_gap.depth.workflow import DepthGapConfig, run_depth_gap
from plugins.sim.model_gap.depth_captures import SIM_NOISE, simulate_captures

SEED0 = 20261204
MAGNITUDES = {"trace": 0.05, "faint": 0.2, "nominal": 1.0}
OUTLIERS = (0.01, 0.05, 0.10)

Job = tuple[str | None, str, int, float, str, float]  # effect, magnitude, seed, alpha, target, outlier fraction


def _floor_mm(z: np.ndarray) -> float:
    """The RMS of the simulated noise itself over the pixels used (mm): what no model can go below."""
    return float(1e3 * np.sqrt(np.mean(SIM_NOISE.sigma(z) ** 2)))


def _inject_flying(caps: DepthCaptures, fraction: float, rng: np.random.Generator) -> list[np.ndarray]:
    """Move *fraction* of each capture's valid pixels 2-20 cm along their ray, either sign (in place);
    the masks (H, W) of the pixels moved."""
    w, h = caps.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    norm = np.sqrt(1.0 + ((u - caps.K[0, 2]) / caps.K[0, 0]) ** 2 + ((v - caps.K[1, 2]) / caps.K[1, 1]) ** 2).ravel()
    masks = []
    for f in caps.frames:
        flat = f.depth.reshape(-1)
        valid = np.flatnonzero(np.isfinite(flat))
        pick = rng.choice(valid, size=max(1, round(fraction * len(valid))), replace=False)
        shift = rng.uniform(0.02, 0.2, len(pick)) * rng.choice((-1.0, 1.0), len(pick))
        flat[pick] = np.maximum(flat[pick] + shift / norm[pick], 0.05)
        mask = np.zeros(h * w, dtype=bool)
        mask[pick] = True
        masks.append(mask.reshape(h, w))
    return masks


def _flag_counts(caps: DepthCaptures, masks: list[np.ndarray], inlier: np.ndarray, target: str) -> tuple[int, ...]:
    """(injected, of them flagged, good pixels flagged): the screen's mask read back by pixel."""
    px = prepare(caps, target)  # the pixels in the order the screen saw them
    moved = np.array([masks[k][int(v), int(u)] for k, u, v in zip(px.capture, px.u, px.v, strict=True)])
    flagged = ~inlier
    return int(moved.sum()), int(np.sum(flagged & moved)), int(np.sum(flagged & ~moved))


def run_case(job: Job) -> dict[str, Any]:
    """One simulated case (:data:`Job`)."""
    effect, magnitude, seed, alpha, target, outliers = job
    caps = simulate_captures(effect, scale=MAGNITUDES[magnitude], seed=seed)
    masks = _inject_flying(caps, outliers, np.random.default_rng(seed + 1)) if outliers else []
    if target == "fit":
        caps.frames = [DepthFrame(f.name, f.depth) for f in caps.frames]
    t0 = time.perf_counter()
    r = run_depth_gap(caps, DepthGapConfig(alpha=alpha, seed=seed, target=target))
    wall = time.perf_counter() - t0
    caps.rejected.clear()
    injected, caught, false_flags = _flag_counts(caps, masks, r.screen.inlier, target) if outliers else (0, 0, 0)
    named = r.named
    tied = [sorted([a.effect.name, *(e.name for e in a.tied_with)]) for a in r.kept if a.tied_with]
    exact = effect is not None and named == [effect]
    floor = _floor_mm(r.pixels.z_ref)
    return {
        "effect": effect,
        "magnitude": magnitude,
        "seed": seed,
        "alpha": alpha,
        "target": target,
        "outlier_fraction": outliers,
        "verdict": r.verdict,
        "named": named,
        "tied": tied,
        "untested": sorted(r.untestable),
        "exact": exact,
        "exact_or_tied": exact or (effect is not None and not named and any(effect in t for t in tied)),
        "wrong_name": any(n != effect for n in named),
        "added_any": bool(r.kept),
        "flagged": r.screen.n_flagged,
        "injected": injected,
        "injected_flagged": caught,
        "false_flags": false_flags,
        "heldout_before_mm": r.baseline_cv.rms_mm,
        "heldout_after_mm": r.final_cv.rms_mm,
        "floor_mm": floor,
        "after_over_floor": r.final_cv.rms_mm / floor,
        "structure_after_p": r.structure_after.p_value,
        "wall_s": wall,
    }


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    verdicts: dict[str, int] = {}
    for r in rows:
        verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
    return {
        "n": len(rows),
        "exact": sum(r["exact"] for r in rows),
        "exact_or_tied": sum(r["exact_or_tied"] for r in rows),
        "wrong_name": sum(r["wrong_name"] for r in rows),
        "added_any": sum(r["added_any"] for r in rows),
        "verdicts": verdicts,
        "heldout_before_mm_median": float(np.median([r["heldout_before_mm"] for r in rows])),
        "heldout_after_mm_median": float(np.median([r["heldout_after_mm"] for r in rows])),
        "after_over_floor_median": float(np.median([r["after_over_floor"] for r in rows])),
        "after_over_floor_max": float(np.max([r["after_over_floor"] for r in rows])),
        "flagged": int(sum(r["flagged"] for r in rows)),
        "injected": int(sum(r["injected"] for r in rows)),
        "injected_flagged": int(sum(r["injected_flagged"] for r in rows)),
        "false_flags": int(sum(r["false_flags"] for r in rows)),
        "cases_flagged_exactly": sum(r["injected_flagged"] == r["injected"] and not r["false_flags"] for r in rows),
        "wall_s_median": float(np.median([r["wall_s"] for r in rows])),
    }


def _jobs(args: argparse.Namespace) -> list[Job]:
    jobs: list[Job] = []
    for k, e in enumerate(CATALOG):
        for mag in MAGNITUDES:
            jobs += [(e.name, mag, SEED0 + 1000 * k + t, 1e-3, "known", 0.0) for t in range(args.trials)]
        jobs += [(e.name, "nominal", SEED0 + 1000 * k + 500 + t, 1e-3, "fit", 0.0) for t in range(args.fit_trials)]
        for frac in OUTLIERS:
            seeds = range(args.outlier_trials)
            jobs += [(e.name, "nominal", SEED0 + 1000 * k + 700 + t, 1e-3, "known", frac) for t in seeds]
    jobs += [(None, "nominal", SEED0 + 100_000 + t, 1e-3, "known", 0.0) for t in range(args.controls)]
    jobs += [(None, "nominal", SEED0 + 200_000 + t, 0.05, "known", 0.0) for t in range(args.controls_loose)]
    jobs += [(None, "nominal", SEED0 + 300_000 + t, 1e-3, "known", 0.05) for t in range(args.outlier_trials)]
    return jobs


def _print(per_effect: dict[str, Any], controls: dict[str, Any]) -> None:
    for key, s in per_effect.items():
        flagged = (
            f"  flying flagged {s['injected_flagged']}/{s['injected']}, false {s['false_flags']}"
            if s["injected"]
            else ""
        )
        print(
            f"{key:34s} exact {s['exact']}/{s['n']}  exact-or-tied {s['exact_or_tied']}/{s['n']}  wrong {s['wrong_name']}"
            f"  held-out {s['heldout_before_mm_median']:.3f} -> {s['heldout_after_mm_median']:.3f} mm"
            f" (after/floor max {s['after_over_floor_max']:.3f}){flagged}"
        )
    for key, s in controls.items():
        print(f"controls {key}: any term added {s['added_any']}/{s['n']}  verdicts {s['verdicts']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per effect and magnitude, poses known (10)")
    ap.add_argument("--fit-trials", type=int, default=5, help="trials per effect, the plane fitted (5)")
    ap.add_argument("--outlier-trials", type=int, default=4, help="trials per effect and flying-pixel share (4)")
    ap.add_argument("--controls", type=int, default=40, help="effect-free controls at alpha 1e-3 (40)")
    ap.add_argument("--controls-loose", type=int, default=60, help="effect-free controls at alpha 0.05 (60)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="1-2 trials, 4 + 10 controls (not the benchmark)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "depth_gap.json"))
    args = ap.parse_args()
    if args.quick:
        args.trials, args.fit_trials, args.outlier_trials, args.controls, args.controls_loose = 2, 1, 1, 4, 10
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as ex:
        rows = list(ex.map(run_case, _jobs(args)))
    effects = [r for r in rows if r["effect"] is not None]
    per_effect: dict[str, Any] = {}
    for e in CATALOG:
        for mag in MAGNITUDES:
            per_effect[f"{e.name}/{mag}"] = _summary(
                [r for r in effects if r["effect"] == e.name and r["magnitude"] == mag and r["target"] == "known"
                 and r["outlier_fraction"] == 0]
            )  # fmt: skip
        per_effect[f"{e.name}/nominal/target fit"] = _summary(
            [r for r in effects if r["effect"] == e.name and r["target"] == "fit"]
        )
        for frac in OUTLIERS:
            per_effect[f"{e.name}/nominal/{frac:.0%} flying"] = _summary(
                [r for r in effects if r["effect"] == e.name and r["outlier_fraction"] == frac]
            )
    clean = [r for r in rows if r["effect"] is None and r["outlier_fraction"] == 0]
    controls = {f"alpha {a:g}": _summary([r for r in clean if r["alpha"] == a]) for a in (1e-3, 0.05)}
    controls["alpha 0.001, 5% flying"] = _summary([r for r in rows if r["effect"] is None and r["outlier_fraction"]])
    result = {
        "benchmark": "depth_gap",
        "machine": machine(),
        "setup": {
            "image": [80, 60],
            "captures": 16,
            "noise": {
                "sigma_const_mm": 1e3 * SIM_NOISE.sigma_const_m,
                "sigma_quad_per_m_mm": 1e3 * SIM_NOISE.sigma_quad_per_m,
            },
            "magnitudes": MAGNITUDES,
            "outlier_fractions": OUTLIERS,
            "seed0": SEED0,
            "trials": {"known": args.trials, "fit": args.fit_trials, "outliers": args.outlier_trials},
        },
        "per_effect": per_effect,
        "controls": controls,
        "wall_s": time.perf_counter() - t0,
        "cases": rows,
    }
    write_result(Path(args.out), result)
    _print(per_effect, controls)


if __name__ == "__main__":
    main()
