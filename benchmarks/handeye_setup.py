"""Finding the hand-eye set-up from the data: how often the right one is taken, refused, or wrong.

Monte Carlo over cells of different difficulty (``simulate.viewing_scene``: pose count, tilt and
roll range, camera noise; robot 0.01 deg / 0.1 mm), alternating eye in hand and eye to hand, each
trial solved with the set-up *not* given (``calibrate_hand_eye(setup="auto")``), once with the
noise estimated and once declared. A trial counts as ``right`` (the true set-up taken), ``refused``
(the set-up test could not tell, verdict degenerate), ``degenerate_motion`` (the motion analysis
refused before any fit) or ``wrong`` (the other set-up taken: the failure that matters).

Then the real files at their defaults: MoveIt's ``pose_samples.json`` (shared data), the shipped
AR-tag sample ``tests/handeye/data/ar_tag_pairs.yml`` and any ``--extra`` file (e.g. a copy of
handeye_calib_camodocal's ``example/TransformPairsOutput.yml``), with the set-up found, Vuong's z,
both set-ups' misfits and the time with the set-up found vs given (wall clock, shared machine).

Usage: ``python benchmarks/handeye_setup.py [--trials 100] [--extra FILE ...]``; writes
benchmarks/results/handeye_setup.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from shared_data import SHARED  # noqa: E402

from plugins.calibration.handeye import HandEyeInputError, NoiseModel, calibrate_hand_eye, load_pose_pairs  # noqa: E402
from plugins.calibration.handeye import simulate as sim  # noqa: E402

#: (poses, max tilt deg, max roll deg, camera deg, camera mm)
CELLS = [
    (15, 35.0, 60.0, 0.1, 0.5),
    (12, 35.0, 60.0, 1.5, 3.0),
    (8, 10.0, 10.0, 1.0, 2.0),
    (6, 15.0, 15.0, 1.0, 2.0),
    (5, 8.0, 8.0, 2.0, 3.0),
    (4, 12.0, 12.0, 1.0, 2.0),
]
SETUPS = ("eye_in_hand", "eye_to_hand")


def simulate(trials: int, seed: int) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for n, tilt, roll, cam_deg, cam_mm in CELLS:
        noise = NoiseModel.isotropic(0.01, 0.1, cam_deg, cam_mm)
        for declared in (False, True):
            counts = dict.fromkeys(("right", "refused", "degenerate_motion", "wrong", "input_error"), 0)
            times: list[float] = []
            for k in range(trials):
                rng = np.random.default_rng(seed + k)
                setup = SETUPS[k % 2]
                scene = sim.viewing_scene(rng, n, setup, max_tilt_deg=tilt, max_roll_deg=roll)
                meas = sim.add_noise(scene, noise, rng)
                t0 = time.perf_counter()
                try:
                    res = calibrate_hand_eye(meas.T_base_tcp, meas.T_cam_target, noise=noise if declared else None)
                except HandEyeInputError:
                    counts["input_error"] += 1
                    continue
                times.append(time.perf_counter() - t0)
                found = res.estimate.get("setup")
                if found == setup:
                    counts["right"] += 1
                elif found is not None:
                    counts["wrong"] += 1
                elif "fit them about equally well" in " ".join(res.reasons):
                    counts["refused"] += 1
                else:
                    counts["degenerate_motion"] += 1
            key = f"{n} poses, tilt {tilt:g} roll {roll:g} deg, camera {cam_deg:g} deg / {cam_mm:g} mm, " + (
                "noise declared" if declared else "noise estimated"
            )
            out[key] = {**counts, "trials": trials, "median_s": float(np.median(times)), "max_s": float(np.max(times))}
            print(key, out[key], flush=True)
    return out


def real_files(paths: list[Path]) -> dict[str, dict[str, object]]:
    out: dict[str, dict[str, object]] = {}
    for path in paths:
        s = load_pose_pairs(path)
        t0 = time.perf_counter()
        res = calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, sample_ids=s.ids)
        t_auto = time.perf_counter() - t0
        setup = res.estimate.get("setup")
        t0 = time.perf_counter()
        if setup is not None:
            calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, setup=setup, sample_ids=s.ids)
        t_given = time.perf_counter() - t0
        m = res.metrics
        x = {"eye_in_hand": "T_tcp_cam", "eye_to_hand": "T_base_cam"}.get(str(setup))
        out[path.name] = {
            "samples": len(s.ids),
            "verdict": res.verdict,
            "setup_found": setup,
            "vuong_z": m.get("setup_vuong_z"),
            "log_likelihood_ratio": m.get("setup_log_likelihood_ratio"),
            "chain_spread_mm_deg": [
                m.get("chain_spread_trans_rms_m", np.nan) * 1e3,
                np.degrees(m.get("chain_spread_rot_rms_rad", np.nan)),
            ],
            "other_setup_chain_spread_mm_deg": [
                m.get("other_setup_chain_spread_trans_rms_m", np.nan) * 1e3,
                np.degrees(m.get("other_setup_chain_spread_rot_rms_rad", np.nan)),
            ],
            "camera_noise_deg_mm": [
                np.degrees(m.get("noise_camera_rot_rad", np.nan)),
                m.get("noise_camera_trans_m", np.nan) * 1e3,
            ],
            "outliers": [s.ids[i] for i in np.flatnonzero(res.outliers)] if res.outliers is not None else [],
            "X_translation_mm": None if x is None else (np.asarray(res.estimate[x])[:3, 3] * 1e3).round(2).tolist(),
            "seconds_setup_found": t_auto,
            "seconds_setup_given": t_given,
        }
        print(path.name, out[path.name], flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--extra", type=Path, nargs="*", default=[], help="more pose-pair files to run at defaults")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "handeye_setup.json")
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore")
    files = [SHARED / "moveit_calibration" / "pose_samples.json", ROOT / "tests/handeye/data/ar_tag_pairs.yml"]
    result = {
        "real_files": real_files(files + list(args.extra)),
        "simulation": simulate(args.trials, args.seed),
        "trials_per_cell": args.trials,
        "seed": args.seed,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
