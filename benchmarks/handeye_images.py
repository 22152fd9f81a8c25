"""Hand-eye from images: vgr against OpenCV 4 on real and rendered board images, from the same detections.

Data (``/work/shared/data``, see its README): ``rwhe_kuka2`` (28 real images, chessboard 25x18 squares
of 15 mm, camera on a KUKA flange, no ground truth) and ``rwhe_synthetic1`` (15 rendered images,
10x7 squares of 200 mm, true ``hand2eye`` and ``base2grid``). Every method gets the same input:
vgr's detections (``detect_images``), the intrinsics calibrated from all images of the set
(``calibrate_intrinsics``) and, for the pose-based methods, the same per-image board poses
(``board_pose``: PnP + LM refinement).

Methods: ``vgr_pose_ml`` (vgr's ML hand-eye solver on the board poses alone, the camera noise from
their covariances), ``vgr`` (the whole pipeline of ``plugins/calibration/boards/handeye_images.py``: ML hand-eye
solver, then the corners' reprojection refinement over the hand-eye and the board's world pose, the
robot poses taken as exact), ``vgr_intrinsics`` (the same, refining the intrinsics too),
``vgr_robot_noise`` / ``vgr_robot_noise_intrinsics`` (``model_robot_noise=True``: every robot pose
corrected under a prior whose sigma is estimated from the corners), OpenCV's ``calibrateHandEye`` (Tsai,
Park, Horaud, Andreff, Daniilidis; the board's world pose is the mean of the training views' own
estimates ``T_base_tcp X T_cam_target``) and ``calibrateRobotWorldHandEye`` (Shah, Li; its own world
pose).

Figures per method and data set:

* ``holdout_rms_px``: leave one view out, fit on the others, predict the held-out view's board pose
  through its robot pose, the hand-eye and the world pose, project the board's corners with the
  camera (for ``vgr_intrinsics`` the camera refined on the training views) and take the RMS
  distance to the detected corners, pooled over all held-out views. The intrinsics all methods start
  from were calibrated with every image (the held-out one included), the same for every method.
* ``spread_mm`` / ``spread_deg``: each view's own estimate of the board's world pose with the
  method's hand-eye (fit to all views) and its PnP board pose, RMS about their mean.
* ``fit_rms_px``: the same projection with the fit to all views, over all views.
* ``ms_per_image``: wall time of the fit to all views divided by the number of images (median over
  ``--repeats``, methods run alternately in each repeat); detection and intrinsics are timed once
  and reported apart (shared by every method).
* vgr's rows: ``std_x_mm`` / ``std_x_deg`` (the reported 1-sigma of the hand-eye, norm over the
  three axes), ``robot_sigma_mm`` / ``robot_sigma_deg`` / ``corner_sigma_px`` (the robot-pose and
  corner noise estimated from the corners, per axis / coordinate); on the synthetic set
  ``gt_x_mahalanobis2``: the hand-eye's error to the ground truth in the reported covariance's metric
  (6 dof: near 6 if the covariance is honest).
* synthetic set: ``gt_x_mm`` / ``gt_x_deg`` (hand-eye) and ``gt_y_mm`` / ``gt_y_deg`` (the board's world
  pose, the ground truth's ``grid`` frame mapped to vgr's ``target`` frame: OpenCV's origin at the
  first inner corner, y down, z into the board) errors to the ground truth.

Usage: ``python benchmarks/handeye_images.py [--repeats 3] [--quick]`` (quick: 1 repeat, no
leave-one-out); writes benchmarks/results/handeye_images.json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_results import machine, write_result  # noqa: E402
from engine.transforms import angle_between, inv, pose_delta  # noqa: E402
from plugins.calibration.boards.board_pose import BoardPose, board_pose  # noqa: E402
from plugins.calibration.boards.detect import Detection, detect_images, image_files  # noqa: E402
from plugins.calibration.boards.handeye_images import calibrate_handeye_images, camera_noise, pair_views  # noqa: E402
from plugins.calibration.boards.intrinsics import calibrate_intrinsics  # noqa: E402
from plugins.calibration.boards.reprojection import mean_pose, view_residuals, world_spread  # noqa: E402
from plugins.calibration.boards.robot_poses import load_robot_poses  # noqa: E402
from plugins.calibration.handeye import calibrate_hand_eye  # noqa: E402
from plugins.camera.board_spec import parse_board  # noqa: E402
from plugins.camera.pinhole import CameraModel  # noqa: E402

F64 = np.ndarray
DATA = Path("/work/shared/data")
SETS = {
    "kuka_2": (DATA / "rwhe_kuka2", "chessboard:25x18:15mm"),
    "synthetic_1": (DATA / "rwhe_synthetic1", "chessboard:10x7:200mm"),
}
# synthetic_1's ground truth (GroundTruth.txt): hand2eye = T_tcp_cam, base2grid = T_base_grid (m)
GT_X = np.diag([1.0, -1.0, -1.0, 1.0])
GT_BASE_GRID = np.array(
    [[-0.0448, -0.0230, 0.9987, 7.6449], [-0.9988, -0.0206, -0.0453, 1.0292], [0.0216, -0.9995, -0.0220, 3.9675],
     [0, 0, 0, 1.0]]
)  # fmt: skip
SETUP = "eye_in_hand"
# vgr's rows: (name, intrinsics refined, robot-pose noise modelled in the pixel refinement)
VGR_ROWS = (
    ("vgr", False, False),
    ("vgr_intrinsics", True, False),
    ("vgr_robot_noise", False, True),
    ("vgr_robot_noise_intrinsics", True, True),
)
COVARIANCE: dict[str, tuple[F64, dict[str, float]]] = {}  # vgr row -> (6x6 covariance of X, metrics), fit to all views
Fit = Callable[[np.ndarray], tuple[F64, F64, CameraModel]]


def _grid_to_target(board_rows: int, square: float) -> F64:
    """``T_grid_target``: OpenCV's chessboard frame (origin at the first inner corner, top left; y
    down, z into the board) to vgr's ``target`` (origin at the bottom-left outer corner, y up, z out)."""
    return np.array([[1, 0, 0, -square], [0, -1, 0, (board_rows - 1) * square], [0, 0, -1, 0], [0, 0, 0, 1.0]])


def _cv_hand_eye(method: int) -> Callable[[F64, F64], tuple[F64, F64]]:
    import cv2

    def solve(M: F64, B: F64) -> tuple[F64, F64]:
        R, t = cv2.calibrateHandEye(list(M[:, :3, :3]), list(M[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]),
                                    method=method)  # fmt: skip
        X = np.eye(4)
        X[:3, :3], X[:3, 3] = R, np.asarray(t).ravel()
        return X, mean_pose(M @ X @ B)

    return solve


def _cv_robot_world(method: int) -> Callable[[F64, F64], tuple[F64, F64]]:
    import cv2

    def solve(M: F64, B: F64) -> tuple[F64, F64]:
        Mi = inv(M)
        Rw, tw, Rc, tc = cv2.calibrateRobotWorldHandEye(
            list(B[:, :3, :3]), list(B[:, :3, 3]), list(Mi[:, :3, :3]), list(Mi[:, :3, 3]), method=method
        )
        T_world_base, T_cam_tcp = np.eye(4), np.eye(4)
        T_world_base[:3, :3], T_world_base[:3, 3] = Rw, np.asarray(tw).ravel()
        T_cam_tcp[:3, :3], T_cam_tcp[:3, 3] = Rc, np.asarray(tc).ravel()
        return inv(T_cam_tcp), inv(T_world_base)

    return solve


def _opencv_methods() -> dict[str, Callable[[F64, F64], tuple[F64, F64]]]:
    import cv2

    return {
        "opencv_tsai": _cv_hand_eye(cv2.CALIB_HAND_EYE_TSAI),
        "opencv_park": _cv_hand_eye(cv2.CALIB_HAND_EYE_PARK),
        "opencv_horaud": _cv_hand_eye(cv2.CALIB_HAND_EYE_HORAUD),
        "opencv_andreff": _cv_hand_eye(cv2.CALIB_HAND_EYE_ANDREFF),
        "opencv_daniilidis": _cv_hand_eye(cv2.CALIB_HAND_EYE_DANIILIDIS),
        "opencv_shah": _cv_robot_world(cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH),
        "opencv_li": _cv_robot_world(cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI),
    }


def _fits(views: list[Detection], M: F64, poses: list[BoardPose], camera: CameraModel) -> dict[str, Fit]:
    B = np.stack([p.T_cam_target for p in poses])
    fits: dict[str, Fit] = {}
    for name, solve in _opencv_methods().items():

        def f(idx: np.ndarray, solve: Callable[[F64, F64], tuple[F64, F64]] = solve) -> tuple[F64, F64, CameraModel]:
            X, Y = solve(M[idx], B[idx])
            return X, Y, camera

        fits[name] = f

    def ml(idx: np.ndarray) -> tuple[F64, F64, CameraModel]:
        res = calibrate_hand_eye(M[idx], B[idx], setup=SETUP, noise=camera_noise([poses[i] for i in idx]),
                                 estimate_noise=True)  # fmt: skip
        return np.asarray(res.estimate["T_tcp_cam"]), np.asarray(res.estimate["T_base_target"]), camera

    fits["vgr_pose_ml"] = ml
    for name, refine, noisy in VGR_ROWS:

        def g(
            idx: np.ndarray, refine: bool = refine, noisy: bool = noisy, name: str = name
        ) -> tuple[F64, F64, CameraModel]:
            out = calibrate_handeye_images([views[i] for i in idx], M[idx], camera, setup=SETUP,
                                           refine_intrinsics=refine, holdout=False, model_robot_noise=noisy)  # fmt: skip
            assert out.refinement is not None, out.result.reasons
            if len(idx) == len(views):
                COVARIANCE[name] = (out.result.covariance[:6, :6], out.result.metrics)
            est = out.result.estimate
            return est["T_tcp_cam"], est["T_base_target"], CameraModel.from_dict(est["camera"])

        fits[name] = g
    return fits


def _rms(res: list[F64]) -> float:
    return float(np.sqrt(np.mean(np.concatenate([np.sum(r**2, axis=1) for r in res]))))


def run_set(name: str, folder: Path, spec: str, repeats: int, loo: bool) -> dict[str, Any]:
    board = parse_board(spec)
    files = image_files([folder])
    t0 = time.perf_counter()
    det = detect_images(files, board)
    t_detect = time.perf_counter() - t0
    t0 = time.perf_counter()
    cal = calibrate_intrinsics(det)
    t_intr = time.perf_counter() - t0
    views, M, _ = pair_views(files, det, load_robot_poses(folder / "RobotPosesVec.txt"))
    cam = cal.camera
    sigma = cal.rms_px / np.sqrt(2.0)
    poses = [board_pose(v, cam, sigma_px=sigma) for v in views]
    B = np.stack([p.T_cam_target for p in poses])
    n = len(views)
    fits = _fits(views, M, poses, cam)
    everything = np.arange(n)
    times: dict[str, list[float]] = {k: [] for k in fits}
    full: dict[str, tuple[F64, F64, CameraModel]] = {}
    for r in range(repeats):
        order = list(fits) if r % 2 == 0 else list(reversed(fits))  # alternate the order between repeats
        for k in order:
            t0 = time.perf_counter()
            full[k] = fits[k](everything)
            times[k].append(time.perf_counter() - t0)
    methods: dict[str, Any] = {}
    for k, fit in fits.items():
        X, Y, c = full[k]
        st, sr, _ = world_spread(SETUP, M, B, X)
        row: dict[str, Any] = {
            "fit_rms_px": _rms(view_residuals(SETUP, M, X, Y, c, views)),
            "spread_mm": st * 1e3,
            "spread_deg": float(np.degrees(sr)),
            "ms_per_image": 1e3 * statistics.median(times[k]) / len(files),
            "T_tcp_cam_mm": (X[:3, 3] * 1e3).round(3).tolist(),
        }
        if loo:
            held = []
            for i in range(n):
                Xi, Yi, ci = fit(np.delete(everything, i))
                held += view_residuals(SETUP, M[i : i + 1], Xi, Yi, ci, [views[i]])
            row["holdout_rms_px"] = _rms(held)
        if k in COVARIANCE:
            cov, m = COVARIANCE[k]
            sd = np.sqrt(np.diag(cov))
            row["std_x_mm"] = float(np.linalg.norm(sd[:3]) * 1e3)  # the reported 1-sigma (norm over the axes)
            row["std_x_deg"] = float(np.degrees(np.linalg.norm(sd[3:])))
            row["robot_sigma_mm"] = m["robot_sigma_trans_m"] * 1e3  # estimated from the corners, per axis
            row["robot_sigma_deg"] = float(np.degrees(m["robot_sigma_rot_rad"]))
            row["corner_sigma_px"] = m["corner_sigma_px"]
        if name == "synthetic_1":
            Y_true = GT_BASE_GRID @ _grid_to_target(board.rows, board.square_m)
            if k in COVARIANCE:  # the error to the ground truth in the reported covariance's metric (6 dof)
                e = pose_delta(X, GT_X)[0]
                row["gt_x_mahalanobis2"] = float(e @ np.linalg.solve(COVARIANCE[k][0], e))
            row["gt_x_mm"] = float(np.linalg.norm(X[:3, 3] - GT_X[:3, 3]) * 1e3)
            row["gt_x_deg"] = float(np.degrees(angle_between(X[:3, :3], GT_X[:3, :3])))
            row["gt_y_mm"] = float(np.linalg.norm(Y[:3, 3] - Y_true[:3, 3]) * 1e3)
            row["gt_y_deg"] = float(np.degrees(angle_between(Y[:3, :3], Y_true[:3, :3])))
        methods[k] = row
        print(name, k, {a: (round(b, 4) if isinstance(b, float) else b) for a, b in row.items()}, flush=True)
    return {
        "images": len(files),
        "views": n,
        "board": spec,
        "intrinsics_rms_px": cal.rms_px,
        "detect_ms_per_image": 1e3 * t_detect / len(files),
        "intrinsics_ms_per_image": 1e3 * t_intr / len(files),
        "methods": methods,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="1 repeat, no leave-one-out")
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "handeye_images.json")
    args = ap.parse_args()
    repeats, loo = (1, False) if args.quick else (args.repeats, True)
    result: dict[str, Any] = {
        "benchmark": "handeye_images",
        "mode": "quick" if args.quick else "full",
        "machine": machine(),
        "sets": {s: run_set(s, *SETS[s], repeats, loo) for s in args.sets},
    }
    if not args.quick:
        write_result(args.out, result)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
