"""Benchmark of the simulated robot's kinematics: FK / Jacobian evaluations per second, vectorised.

Measures, for the shipped UR5e model, ``RobotModel.fk`` and ``RobotModel.jacobian`` on N random
configurations per call (N = 1 ... 100 000), the parameter Jacobian that kinematic calibration uses,
and numerical IK solves per second. Reference in the same run: a plain per-pose loop of 4x4 DH
matrix products in numpy (what a straightforward implementation does). ``benchmarks/sim.py``
(simulated cell benchmark) can import :func:`measure` to report the same figures.

Run: ``PYTHONPATH=. python benchmarks/sim_kinematics.py`` -> benchmarks/results/sim_kinematics.json
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from bench_results import machine, write_result

from plugins.robot.model_file import load_robot_model

SEED = 0
SIZES = (1, 100, 10_000, 100_000)


def _best_rate(fn, n: int, min_time_s: float = 0.3, repeats: int = 5) -> float:
    """Evaluations per second: best of ``repeats`` timed batches (each >= min_time_s)."""
    fn()  # warm up
    rates = []
    for _ in range(repeats):
        calls, t0 = 0, time.perf_counter()
        while True:
            fn()
            calls += 1
            dt = time.perf_counter() - t0
            if dt >= min_time_s / repeats:
                break
        rates.append(calls * n / dt)
    return float(max(rates))


def _loop_dh_fk(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Reference: one 4x4 product per joint per pose, in a Python loop."""
    out = np.empty((q.shape[0], 4, 4))
    for i, qi in enumerate(q):
        T = np.eye(4)
        for (a, alpha, d, theta), qj in zip(dh, qi, strict=True):
            ct, st = np.cos(theta + qj), np.sin(theta + qj)
            ca, sa = np.cos(alpha), np.sin(alpha)
            T = T @ np.array(
                [
                    [ct, -st * ca, st * sa, a * ct],
                    [st, ct * ca, -ct * sa, a * st],
                    [0, sa, ca, d],
                    [0, 0, 0, 1],
                ]
            )
        out[i] = T
    return out


def measure(sizes=SIZES, seed: int = SEED) -> dict:
    model = load_robot_model("ur5e")
    rng = np.random.default_rng(seed)
    rows = model.dh_rows()
    dh = np.array([[r.a, r.alpha, r.d, r.theta] for r in rows])
    results: dict = {"fk": {}, "jacobian": {}, "param_jacobian": {}, "loop_dh_fk_reference": {}}
    for n in sizes:
        q = rng.uniform(-np.pi, np.pi, size=(n, model.dof))
        results["fk"][str(n)] = _best_rate(lambda q=q: model.fk(q), n)
        results["jacobian"][str(n)] = _best_rate(lambda q=q: model.jacobian(q), n)
        results["param_jacobian"][str(n)] = _best_rate(lambda q=q: model.param_jacobian(q), n)
        if n <= 10_000:
            results["loop_dh_fk_reference"][str(n)] = _best_rate(lambda q=q: _loop_dh_fk(dh, q), n)
    q_check = rng.uniform(-np.pi, np.pi, size=(100, model.dof))
    assert np.allclose(_loop_dh_fk(dh, q_check), model.fk(q_check), atol=1e-12)
    targets = model.fk(rng.uniform(-np.pi, np.pi, size=(20, model.dof)))
    t0 = time.perf_counter()
    ok = sum(model.ik(T, rng_seed=seed).success for T in targets)
    results["ik_random_seed_solves_per_s"] = len(targets) / (time.perf_counter() - t0)
    results["ik_successes"] = f"{ok}/{len(targets)}"
    return results


def main() -> None:
    results = measure()
    out = {
        "benchmark": "sim_kinematics",
        "unit": "evaluations per second (poses per second for batched calls)",
        "model": "ur5e",
        "seed": SEED,
        "sizes": list(SIZES),
        "machine": machine(),
        "results": results,
    }
    path = Path(__file__).parent / "results" / "sim_kinematics.json"
    write_result(path, out)
    for key in ("fk", "jacobian", "param_jacobian", "loop_dh_fk_reference"):
        print(key, {k: f"{v:,.0f}/s" for k, v in results[key].items()})
    print("ik", f"{results['ik_random_seed_solves_per_s']:.1f} solves/s", results["ik_successes"])
    print("wrote", path)


if __name__ == "__main__":
    main()
