"""The fine-registration backends behind one signature: small_gicp (GICP, point-to-plane), Open3D
(point-to-plane, generalized ICP) and KISS-ICP (point-to-point against its voxel hash map).

Every backend estimates ``T_target_source`` with source = CURRENT and target = TEMPLATE, i.e.
``T_match`` (see ``result.py``). They only iterate; validation, scoring, uncertainty and the verdict
are done once for all backends in ``fine.py``.

Thread counts: ``num_threads`` parallelises only the per-point state (small_gicp's k-d tree, normals
and covariances), whose results do not depend on it. The ICP iterations themselves always run on
ONE thread (:data:`SOLVER_THREADS`): their Hessian/gradient reductions, summed in a scheduling-
dependent order on several threads, changed the last bits, then the stopping iteration, and the
pose by up to 1e-6 (m / rad; measured with 2 threads on small_gicp and Open3D), also run to run.
So a result is bit-identical at any thread count (tests/registration/test_registration_determinism.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import open3d as o3d
import small_gicp

from plugins.registration.determinism import open3d_threads
from plugins.registration.preprocess import PreparedCloud

#: Threads of the ICP solvers' iterations (see the module docstring): always one.
SOLVER_THREADS = 1

#: Open3D stops when the relative changes of fitness and inlier RMSE both fall below this.
OPEN3D_RELATIVE_TOLERANCE = 1e-7

Backend = Literal["small_gicp_gicp", "small_gicp_plane", "open3d_plane", "open3d_gicp", "kiss_icp"]
BACKENDS: tuple[str, ...] = get_args(Backend)


@dataclass(frozen=True)
class IcpSettings:
    max_correspondence_m: float
    max_iterations: int
    rotation_eps_rad: float
    translation_eps_m: float
    num_threads: int
    kiss_voxel_m: float
    kiss_points_per_voxel: int


@dataclass
class BackendOutput:
    T_match: np.ndarray
    iterations: int  # -1 when the backend does not report it
    converged: bool


def _small_gicp(
    kind: str,
) -> Callable[[PreparedCloud, PreparedCloud, np.ndarray, IcpSettings], BackendOutput]:
    def run(current: PreparedCloud, template: PreparedCloud, T_init: np.ndarray, s: IcpSettings) -> BackendOutput:
        tgt, tgt_tree = template.small_gicp(s.num_threads)
        src, _ = current.small_gicp(s.num_threads)
        res = small_gicp.align(
            tgt,
            src,
            tgt_tree,
            init_T_target_source=T_init,
            registration_type=kind,
            max_correspondence_distance=s.max_correspondence_m,
            num_threads=SOLVER_THREADS,
            max_iterations=s.max_iterations,
            rotation_epsilon=s.rotation_eps_rad,
            translation_epsilon=s.translation_eps_m,
        )
        return BackendOutput(np.array(res.T_target_source), int(res.iterations), bool(res.converged))

    return run


def _open3d(kind: str) -> Callable[[PreparedCloud, PreparedCloud, np.ndarray, IcpSettings], BackendOutput]:
    reg = o3d.pipelines.registration

    def run(current: PreparedCloud, template: PreparedCloud, T_init: np.ndarray, s: IcpSettings) -> BackendOutput:
        crit = reg.ICPConvergenceCriteria(
            relative_fitness=OPEN3D_RELATIVE_TOLERANCE,
            relative_rmse=OPEN3D_RELATIVE_TOLERANCE,
            max_iteration=s.max_iterations,
        )
        src, tgt = current.open3d(), template.open3d()
        with open3d_threads(SOLVER_THREADS):
            if kind == "plane":
                res = reg.registration_icp(
                    src, tgt, s.max_correspondence_m, T_init, reg.TransformationEstimationPointToPlane(), crit
                )
            else:
                res = reg.registration_generalized_icp(
                    src,
                    tgt,
                    s.max_correspondence_m,
                    T_init,
                    reg.TransformationEstimationForGeneralizedICP(),
                    crit,
                )
        # Open3D 0.20's Python result reports neither iterations nor convergence.
        return BackendOutput(np.array(res.transformation), -1, True)

    return run


def _kiss_icp(current: PreparedCloud, template: PreparedCloud, T_init: np.ndarray, s: IcpSettings) -> BackendOutput:
    from kiss_icp.mapping import VoxelHashMap
    from kiss_icp.registration import Registration

    key = ("kiss_map", s.kiss_voxel_m, s.kiss_points_per_voxel)
    vmap = template._cache.get(key)
    if vmap is None:
        vmap = VoxelHashMap(voxel_size=s.kiss_voxel_m, max_distance=1e6, max_points_per_voxel=s.kiss_points_per_voxel)
        vmap.add_points(template.points)
        template._cache[key] = vmap
    registration = Registration(
        max_num_iterations=s.max_iterations,
        convergence_criterion=s.translation_eps_m,
        max_num_threads=SOLVER_THREADS,
    )
    T = registration.align_points_to_map(
        points=current.points,
        voxel_map=vmap,
        initial_guess=np.asarray(T_init, dtype=float),
        max_correspondance_distance=s.max_correspondence_m,
        kernel=s.max_correspondence_m / 3.0,
    )
    return BackendOutput(np.array(T), -1, True)


RUNNERS: dict[str, Callable[[PreparedCloud, PreparedCloud, np.ndarray, IcpSettings], BackendOutput]] = {
    "small_gicp_gicp": _small_gicp("GICP"),
    "small_gicp_plane": _small_gicp("PLANE_ICP"),
    "open3d_plane": _open3d("plane"),
    "open3d_gicp": _open3d("gicp"),
    "kiss_icp": _kiss_icp,
}


def run_backend(
    name: str, current: PreparedCloud, template: PreparedCloud, T_init: np.ndarray, settings: IcpSettings
) -> BackendOutput:
    """Run backend *name* (one of :data:`BACKENDS`) from ``T_init``."""
    try:
        runner = RUNNERS[name]
    except KeyError:
        raise ValueError(f"unknown fine backend {name!r}; choose one of {', '.join(BACKENDS)}") from None
    return runner(current, template, T_init, settings)
