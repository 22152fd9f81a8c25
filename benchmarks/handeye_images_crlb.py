"""Hand-eye from images on simulated boards: vgr's error against the Cramér–Rao bound, and the honesty
of its reported covariance.

Data: :func:`plugins.calibration.boards.handeye_sim.simulate_handeye` (eye in hand, ``SIM_CAMERA``
640x480 with barrel distortion, ``chessboard:10x7:30mm``, 15 views per trial, the true hand-eye
``TRUE_X`` and board pose ``TRUE_Y``; the intrinsics are given exact). Each trial is one seed
(``SEED0 + k``); the estimate is :func:`plugins.calibration.boards.handeye_images.calibrate_handeye_images`
(no held-out figures). Errors are ``pose_delta(X_est, X_true)`` (mm, rad: translation, rotation
vector), the perturbation in which the refinement and its covariance are written.

Scenarios:

* ``corner_noise``: the exact projections plus ``N(0, 0.1²)`` px per coordinate, the robot poses
  exact: the model of the pixel refinement. ``crlb``:
  :func:`plugins.calibration.boards.reprojection.crlb` at the truth (same views, same noise).
* ``corner_and_robot_noise``: the same, and every robot pose perturbed by ``N(0, 0.2 mm)`` per axis
  and ``N(0, 0.02 deg)`` per rotation axis; its ``crlb`` has the true robot poses as nuisance
  parameters observed through the perturbed ones (the model of ``model_robot_noise=True``).
* ``rendered`` / ``rendered_robot_noise``: the views rendered (:func:`.render.render_board`, blur
  0.8 px, grey noise 2) and detected (OpenCV's SB chessboard detector: its error is in part shared
  by a view's corners), robot poses exact / with the noise above. No CRLB (the detector's error is
  not a known model); the covariance check only.

Figures per estimator (``default``: robot poses exact in the fit, the covariance with the robot and
corner noise estimated from the corners; ``robot_noise``: ``model_robot_noise=True``):
``rms_trans_mm`` / ``rms_rot_deg`` (RMS over the trials of the hand-eye's translation / rotation
error, norm over the axes), ``crlb_trans_mm`` / ``crlb_rot_deg`` (the square root of the trials'
mean CRLB trace), ``ratio_*`` (RMS / bound, with a bootstrap 95 % interval over the trials),
``crlb_mahalanobis2_mean`` (the error in the CRLB's metric, 6 dof: 6 for an efficient estimator)
and ``mahalanobis2_mean`` / ``_median`` (in the reported covariance's metric: 6 / 5.35 if honest),
``outlier_views`` (views the pipeline left out, over all trials).

Usage: ``python benchmarks/handeye_images_crlb.py [--trials N]`` (default: 400 and 150 for the
point-noise scenarios, 30 for the rendered ones); writes benchmarks/results/handeye_images_crlb.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_results import machine, write_result  # noqa: E402
from engine.transforms import pose_delta  # noqa: E402
from plugins.calibration.boards.handeye_images import calibrate_handeye_images  # noqa: E402
from plugins.calibration.boards.handeye_sim import SIM_CAMERA, simulate_handeye  # noqa: E402
from plugins.calibration.boards.reprojection import RobotNoise, crlb  # noqa: E402
from plugins.camera.board_spec import parse_board  # noqa: E402

BOARD = parse_board("chessboard:10x7:30mm")
N_VIEWS = 15
SIGMA_PX = 0.1
ROBOT = RobotNoise(2e-4, float(np.radians(0.02)))
SEED0 = 20261127
# scenario -> (default trials, robot noise, rendered, estimators)
SCENARIOS: dict[str, tuple[int, RobotNoise | None, bool, tuple[str, ...]]] = {
    "corner_noise": (400, None, False, ("default",)),
    "corner_and_robot_noise": (150, ROBOT, False, ("default", "robot_noise")),
    "rendered": (30, None, True, ("default", "robot_noise")),
    "rendered_robot_noise": (30, ROBOT, True, ("default", "robot_noise")),
}


def _ratio_ci(err2: np.ndarray, bound2: np.ndarray, rng: np.random.Generator) -> list[float]:
    """Bootstrap 95 % interval of sqrt(mean err²) / sqrt(mean bound²) over the trials."""
    k = rng.integers(0, len(err2), (2000, len(err2)))
    r = np.sqrt(err2[k].mean(axis=1) / bound2[k].mean(axis=1))
    return [float(x) for x in np.percentile(r, [2.5, 97.5])]


def run(name: str, trials: int, robot: RobotNoise | None, render: bool, estimators: tuple[str, ...]) -> dict[str, Any]:
    rows: dict[str, list[list[float]]] = {e: [] for e in estimators}
    bounds: list[np.ndarray] = []
    t0 = time.perf_counter()
    for k in range(trials):
        sim = simulate_handeye(
            BOARD, SIM_CAMERA, N_VIEWS, np.random.default_rng(SEED0 + k), sigma_px=SIGMA_PX, robot_noise=robot,
            render=render,
        )  # fmt: skip
        C = None
        if not render:
            C = crlb("eye_in_hand", sim.T_base_tcp_true, sim.views, SIM_CAMERA, sim.X, sim.Y, SIGMA_PX,
                     robot_noise=robot)[:6, :6]  # fmt: skip
            bounds.append(np.diag(C))
        for est in estimators:
            out = calibrate_handeye_images(
                sim.views, sim.T_base_tcp, SIM_CAMERA, holdout=False, model_robot_noise=est == "robot_noise"
            )
            e = pose_delta(out.result.estimate["T_tcp_cam"], sim.X)[0]
            cov = out.result.covariance[:6, :6]
            m2_crlb = float(e @ np.linalg.solve(C, e)) if C is not None else float("nan")
            rows[est].append([*(e**2), float(e @ np.linalg.solve(cov, e)), m2_crlb, len(out.outlier_views)])
    seconds = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    result: dict[str, Any] = {"trials": trials, "robot_noise": robot is not None, "rendered": render}
    B = np.array(bounds) if bounds else None
    if B is not None:
        result["crlb_trans_mm"] = float(np.sqrt(B[:, :3].sum(axis=1).mean()) * 1e3)
        result["crlb_rot_deg"] = float(np.degrees(np.sqrt(B[:, 3:].sum(axis=1).mean())))
    for est, r in rows.items():
        a = np.array(r)
        et, er = a[:, :3].sum(axis=1), a[:, 3:6].sum(axis=1)
        row: dict[str, Any] = {
            "rms_trans_mm": float(np.sqrt(et.mean()) * 1e3),
            "rms_rot_deg": float(np.degrees(np.sqrt(er.mean()))),
            "mahalanobis2_mean": float(a[:, 6].mean()),
            "mahalanobis2_median": float(np.median(a[:, 6])),
            "outlier_views": int(a[:, 8].sum()),
        }
        if B is not None:
            bt, br = B[:, :3].sum(axis=1), B[:, 3:].sum(axis=1)
            row["ratio_trans"] = float(np.sqrt(et.mean() / bt.mean()))
            row["ratio_trans_ci95"] = _ratio_ci(et, bt, rng)
            row["ratio_rot"] = float(np.sqrt(er.mean() / br.mean()))
            row["ratio_rot_ci95"] = _ratio_ci(er, br, rng)
            row["crlb_mahalanobis2_mean"] = float(a[:, 7].mean())
        result[est] = row
        print(name, est, {k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    result["seconds_per_trial"] = seconds / trials
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=None, help="trials per scenario (default: each scenario's own)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "handeye_images_crlb.json")
    args = ap.parse_args()
    result: dict[str, Any] = {
        "benchmark": "handeye_images_crlb",
        "mode": "full" if args.trials is None else f"{args.trials} trials",
        "machine": machine(),
        "board": BOARD.describe(),
        "views": N_VIEWS,
        "sigma_px": SIGMA_PX,
        "robot_sigma_mm": ROBOT.trans_m * 1e3,
        "robot_sigma_deg": float(np.degrees(ROBOT.rot_rad)),
        "seed0": SEED0,
        "scenarios": {},
    }
    for s in args.scenarios:
        n, robot, render, estimators = SCENARIOS[s]
        result["scenarios"][s] = run(s, args.trials or n, robot, render, estimators)
    if args.trials is None:
        write_result(args.out, result)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
