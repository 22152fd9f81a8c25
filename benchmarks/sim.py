"""Benchmark of the simulated cell: depth render time per 640 x 480 frame, FK / Jacobian rates.

Depth camera (target < 30 ms per 640 x 480 frame on the 2-core machine): ``DepthCameraModel.render``
and ``render_with_truth`` (what the ``sim_camera`` stage runs) on two scenes, measured next to the
floor it cannot beat, Open3D's own ray cast of the same scene (``RaycastingScene`` built from the
same meshes + ``create_rays_pinhole`` + ``cast_rays``, no noise, no image assembly).  The difference
is vgr's cost for noise, dropouts, range limits and the image and cloud outputs (the organised
cloud, normals, pixel coordinates and per-point truth are assembled on first access, so they are
not in these times).

* ``feature_part``: the feature part alone at ~0.6 m (eye-in-hand inspection view).
* ``seed004_cell``: the 400 x 320 mm base plate with the planar plate on it, filling most of the image
  (the worst case: most rays hit), the plate assembled on it.

Kinematics: ``RobotModel.fk`` and ``RobotModel.jacobian`` of the shipped UR5e model
(``plugins/robot/kinematics.py`` from the sim-kin branch), vectorised over N random configurations,
in evaluations (poses) per second; ``benchmarks/sim_kinematics.py`` has the fuller kinematics study.

Run: ``PYTHONPATH=. python benchmarks/sim.py`` -> ``benchmarks/results/sim.json``.  The machine is
shared, so the load average before and after is recorded; compare figures from one run only.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import open3d as o3d

from engine.transforms import T_from_rotvec, inv
from plugins.sim.camera import DepthCameraModel, DepthNoiseModel, default_intrinsics, look_at
from plugins.util.workpieces import assembled_plate_pose, make_workpiece

SEED = 0
REPEATS = 40
FK_SIZES = (1, 100, 10_000)


def _stats(wall: list[float], cpu: list[float]) -> dict[str, float]:
    a, c = np.array(wall), np.array(cpu)
    return {
        "median_ms": float(np.median(a)),
        "p10_ms": float(np.percentile(a, 10)),
        "p90_ms": float(np.percentile(a, 90)),
        "cpu_median_ms": float(np.median(c)),  # process CPU time, all threads: steadier under load
    }


def _interleaved_ms(fns: dict, repeats: int) -> dict[str, dict[str, float]]:
    """Time each function ``repeats`` times, alternating them so load changes hit all alike."""
    for fn in fns.values():
        fn()
        fn()  # warm up (first BVH build, allocator)
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for key, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[key].append((time.perf_counter() - t0) * 1e3)
            cpu[key].append((time.process_time() - c0) * 1e3)
    return {k: _stats(wall[k], cpu[k]) for k in fns}


def _scenes() -> dict[str, tuple[list, np.ndarray]]:
    part = make_workpiece("feature_part")
    plate, base = make_workpiece("planar_plate"), make_workpiece("base_plate")
    return {
        "feature_part": (
            [(part, T_from_rotvec([0.0, 0.0, 0.3], [0.0, 0.0, 0.0]))],
            look_at([0.25, 0.2, 0.5], [0.0, 0.0, 0.03]),
        ),
        "seed004_cell": (
            [(base, np.eye(4)), (plate, assembled_plate_pose())],
            look_at([0.1, 0.05, 0.6], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0)),
        ),
    }


def _open3d_cast(parts, T_world_cam, intrinsics) -> int:
    scene = o3d.t.geometry.RaycastingScene()
    for part, T in parts:
        mesh = o3d.t.geometry.TriangleMesh.from_legacy(part.mesh).transform(T)
        scene.add_triangles(mesh)
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(intrinsics.K),
        o3d.core.Tensor(inv(T_world_cam)),
        intrinsics.width,
        intrinsics.height,
    )
    hits = scene.cast_rays(rays)
    return int(np.isfinite(hits["t_hit"].numpy()).sum())


def measure_render(repeats: int = REPEATS) -> dict:
    intrinsics = default_intrinsics()
    camera = DepthCameraModel(intrinsics, DepthNoiseModel.realsense_d415())
    rng = np.random.default_rng(SEED)
    out = {}
    for name, (parts, T_world_cam) in _scenes().items():
        n_points = len(camera.render(parts, T_world_cam, rng).points)
        timing = _interleaved_ms(
            {
                "vgr_render": lambda p=parts, T=T_world_cam: camera.render(p, T, rng),
                "vgr_render_with_truth": lambda p=parts, T=T_world_cam: camera.render_with_truth(p, T, rng),
                "open3d_cast_only": lambda p=parts, T=T_world_cam: _open3d_cast(p, T, intrinsics),
            },
            repeats,
        )
        out[name] = {
            "valid_points": n_points,
            "rays_hit": _open3d_cast(parts, T_world_cam, intrinsics),
            **timing,
        }
    return out


def _rate(fn, n: int, repeats: int = 5, min_time_s: float = 0.2) -> float:
    fn()
    best = 0.0
    for _ in range(repeats):
        calls, t0 = 0, time.perf_counter()
        while (dt := time.perf_counter() - t0) < min_time_s or calls == 0:
            fn()
            calls += 1
        best = max(best, calls * n / dt)
    return best


def measure_kinematics() -> dict:
    try:
        from plugins.robot.model_file import load_robot_model
    except ImportError as exc:  # the kinematics branch has not been merged
        return {"error": f"plugins.robot.kinematics not available: {exc}"}
    model = load_robot_model("ur5e")
    rng = np.random.default_rng(SEED)
    out: dict = {"model": "ur5e", "fk_per_s": {}, "jacobian_per_s": {}, "fk_and_jacobian_per_s": {}}
    for n in FK_SIZES:
        q = rng.uniform(model.lower, model.upper, size=(n, model.dof))
        out["fk_per_s"][str(n)] = _rate(lambda q=q: model.fk(q), n)
        out["jacobian_per_s"][str(n)] = _rate(lambda q=q: model.jacobian(q), n)
        out["fk_and_jacobian_per_s"][str(n)] = _rate(lambda q=q: model.fk_and_jacobian(q), n)
    return out


def main() -> None:
    load_before = os.getloadavg()
    render = measure_render()
    kinematics = measure_kinematics()
    out = {
        "benchmark": "sim",
        "seed": SEED,
        "parameters": {
            "image": "640x480, 60 deg HFOV",
            "noise": "DepthNoiseModel.realsense_d415()",
            "repeats": REPEATS,
            "fk_sizes": list(FK_SIZES),
            "render_target_ms": 30.0,
        },
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "open3d": o3d.__version__,
            "load_average_before": load_before,
            "load_average_after": os.getloadavg(),
            "note": "shared 2-core machine: timings are noisy, compare figures within one run",
        },
        "render": render,
        "kinematics": kinematics,
    }
    path = Path(__file__).parent / "results" / "sim.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2) + "\n")
    for name, r in render.items():
        print(
            f"{name}: vgr render {r['vgr_render']['median_ms']:.1f} ms "
            f"(p90 {r['vgr_render']['p90_ms']:.1f}; with truth {r['vgr_render_with_truth']['median_ms']:.1f}), "
            f"open3d cast only {r['open3d_cast_only']['median_ms']:.1f} ms; CPU time "
            f"{r['vgr_render']['cpu_median_ms']:.1f} vs {r['open3d_cast_only']['cpu_median_ms']:.1f} ms; "
            f"{r['valid_points']} points"
        )
    if "error" in kinematics:
        print("kinematics:", kinematics["error"])
    else:
        for key in ("fk_per_s", "jacobian_per_s", "fk_and_jacobian_per_s"):
            print(key, {k: f"{v:,.0f}/s" for k, v in kinematics[key].items()})
    print("load average before/after", load_before, os.getloadavg())
    print("wrote", path)


if __name__ == "__main__":
    main()
