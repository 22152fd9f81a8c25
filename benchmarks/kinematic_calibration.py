"""Benchmark: kinematic calibration accuracy against the Cramér-Rao bound, and seed 003's method.

Monte-Carlo on the simulated UR5e: random errors of 0.2 mm / 0.2 mrad on every DH parameter, an
unknown tracker frame and tool point, fixed poses (60 for calibration, 200 held out), 0.05 mm noise
per axis, ``--trials`` noise realisations (seeded). Reported for vgr:

* RMS parameter error / CRLB sigma per identified joint/tool parameter (median, max) and the mean
  normalised squared error (1.0 = exactly at the bound), the reported covariance's calibration;
* held-out position RMS per axis (noise floor: 0.05 mm), iterations, time per calibration.

Reference in the same run: seed 003's algorithm (Gauss-Newton on *all* DH parameters with ridge
1e-6, step limited to 0.01, stop on small step / stalled error), same initial frames and data.

Run: ``PYTHONPATH=. python benchmarks/kinematic_calibration.py [--trials 100]``
-> benchmarks/results/kinematic_calibration.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from kinematic_calibration.kincal_sim import NOISE_M, measure, nominal_model, random_poses, true_robot

from plugins.solvers.kinematic_calibration import (
    KinematicCalibrationConfig,
    KinematicSamples,
    calibrate_kinematics,
    candidate_parameters,
)
from plugins.solvers.kinematic_calibration.calibrate import initial_frames

SEED = 0


def seed003_gauss_newton(model, samples, max_iterations=50, ridge=1e-6, max_step=0.01, tol=1e-6):
    """Seed 003: dphi = (J^T J + ridge I)^-1 J^T e on every parameter, |dphi| <= max_step."""
    work = initial_frames(model, samples, True, True)
    names = candidate_parameters(work, False, KinematicCalibrationConfig())
    idx = [work.chain.index(n) for n in names]
    v = work.param_values.copy()
    errors = []
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007
        T, J = work.param_jacobian(samples.q, v, frame="base")
        e = (samples.positions - T[:, :3, 3]).ravel()
        Jp = J[:, :3, idx].reshape(-1, len(idx))
        dphi = np.linalg.solve(Jp.T @ Jp + ridge * np.eye(len(idx)), Jp.T @ e)
        n = np.linalg.norm(dphi)
        if n > max_step:
            dphi *= max_step / n
        v[idx] += dphi
        errors.append(float(np.linalg.norm(e)))
        if errors[-1] < tol or n < tol or (len(errors) > 5 and abs(errors[-1] - errors[-6]) < tol * 10):
            break
    return work.with_values(v), it


def _values(model, names):
    d = dict(zip(model.param_names, model.param_values, strict=True))
    return np.array([d[n] for n in names])


def _holdout_rms_per_axis_mm(model, hold):
    e = hold.positions - model.fk(hold.q)[:, :3, 3]
    return float(np.sqrt(np.mean(e**2)) * 1e3)


def run(trials: int) -> dict:
    truth = true_robot("ur5e", seed=21)
    model = nominal_model("ur5e")
    q = random_poses(model, 60, seed=22)
    hold = measure(truth, random_poses(model, 200, seed=23), seed=24)
    ref = calibrate_kinematics(
        model,
        KinematicSamples(q, truth.fk(q)[:, :3, 3]),
        config=KinematicCalibrationConfig(holdout_fraction=0.0, trust_noise=True),
    )
    names = [n for n in ref.result.param_names if not n.startswith("base.")]
    sel = [ref.result.param_names.index(n) for n in names]
    crlb = ref.result.covariance[np.ix_(sel, sel)]
    x_ref = _values(ref.model, names)
    errs, mahal_rep, iters, times, hold_vgr, hold_seed, iters_seed, times_seed = (
        [],
        [],
        [],
        [],
        [],
        [],
        [],
        [],
    )
    for k in range(trials):
        data = measure(truth, q, seed=1000 + k)
        t0 = time.perf_counter()
        out = calibrate_kinematics(model, data, config=KinematicCalibrationConfig(holdout_fraction=0.0))
        times.append(time.perf_counter() - t0)
        iters.append(out.result.iterations)
        e = _values(out.model, names) - x_ref
        errs.append(e)
        mahal_rep.append(float(e @ np.linalg.solve(out.result.covariance[np.ix_(sel, sel)], e)) / len(names))
        hold_vgr.append(_holdout_rms_per_axis_mm(out.model, hold))
        t0 = time.perf_counter()
        seed_model, seed_it = seed003_gauss_newton(model, data)
        times_seed.append(time.perf_counter() - t0)
        iters_seed.append(seed_it)
        hold_seed.append(_holdout_rms_per_axis_mm(seed_model, hold))
    E = np.array(errs)
    ratio = np.sqrt(np.mean(E**2, axis=0)) / np.sqrt(np.diag(crlb))
    mahal = float(np.mean([e @ np.linalg.solve(crlb, e) for e in E]) / len(names))
    return {
        "identified_parameters": ref.result.param_names,
        "compared_parameters": names,
        "vgr": {
            "rms_error_over_crlb_sigma": dict(zip(names, ratio.round(4).tolist(), strict=True)),
            "rms_error_over_crlb_median": float(np.median(ratio)),
            "rms_error_over_crlb_max": float(ratio.max()),
            "mean_normalised_squared_error": mahal,
            "reported_covariance_mean_normalised_squared_error": float(np.mean(mahal_rep)),
            "holdout_rms_per_axis_mm_mean": float(np.mean(hold_vgr)),
            "iterations_median": float(np.median(iters)),
            "iterations_max": int(np.max(iters)),
            "seconds_per_calibration_median": float(np.median(times)),
        },
        "seed003_gauss_newton_ridge": {
            "holdout_rms_per_axis_mm_mean": float(np.mean(hold_seed)),
            "holdout_rms_per_axis_mm_max": float(np.max(hold_seed)),
            "iterations_median": float(np.median(iters_seed)),
            "iterations_max": int(np.max(iters_seed)),
            "seconds_per_calibration_median": float(np.median(times_seed)),
        },
        "noise_floor_per_axis_mm": NOISE_M * 1e3,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    args = ap.parse_args()
    results = run(args.trials)
    out = {
        "benchmark": "kinematic_calibration",
        "seed": SEED,
        "parameters": {
            "robot": "ur5e",
            "dh_errors": "0.2 mm / 0.2 mrad one sigma on theta, d, a, alpha, beta of every joint",
            "noise_per_axis_m": NOISE_M,
            "calibration_poses": 60,
            "holdout_poses": 200,
            "trials": args.trials,
            "measurement": "tool point position (laser-tracker-like), unknown tracker frame and tool point",
        },
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "numpy": np.__version__,
            "note": "shared 2-core machine, timings are noisy",
        },
        "results": results,
    }
    path = Path(__file__).parent / "results" / "kinematic_calibration.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    v, s = results["vgr"], results["seed003_gauss_newton_ridge"]
    lines = [
        f"vgr: RMS error / CRLB sigma median {v['rms_error_over_crlb_median']:.3f}, "
        f"max {v['rms_error_over_crlb_max']:.3f}",
        f"vgr: mean normalised squared error {v['mean_normalised_squared_error']:.3f} (1 = at the CRLB)",
        f"vgr: reported covariance {v['reported_covariance_mean_normalised_squared_error']:.3f} (1 = honest)",
        f"vgr: held-out RMS per axis {v['holdout_rms_per_axis_mm_mean']:.4f} mm (floor {NOISE_M * 1e3:.3f})",
        f"vgr: iterations median {v['iterations_median']}, max {v['iterations_max']}",
        f"seed 003 GN+ridge: held-out RMS per axis {s['holdout_rms_per_axis_mm_mean']:.4f} mm, "
        f"iterations median {s['iterations_median']}, max {s['iterations_max']}",
    ]
    print("\n".join(lines))
    print("wrote", path)


if __name__ == "__main__":
    main()
