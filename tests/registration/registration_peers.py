"""The peers vgr's matchers are compared with, called the way their documentation shows, with settings
sized for workpieces (metres, 2 mm voxels) and the same convergence tolerances as vgr's fine stage.

* ``small_gicp_gicp``: ``small_gicp.align`` on the raw clouds (it downsamples, estimates covariances
  and registers); single-threaded.
* ``open3d_point_to_plane``: Open3D voxel downsampling, KNN normals, ``registration_icp`` with
  ``TransformationEstimationPointToPlane``.
* ``kiss_icp``: KISS-ICP's voxel hash map of the template and ``Registration.align_points_to_map``
  (point-to-point with its Geman-McClure kernel).
* ``open3d_fpfh_ransac``: Open3D's global-registration tutorial pipeline (FPFH radius 5 voxels,
  RANSAC with mutual filter, edge-length and distance checkers), seeded and single-threaded.
* ``paper_baseline``: seed 004's "RANSAC + ICP": ``open3d_fpfh_ransac`` then Open3D point-to-plane ICP.

Every function maps CURRENT onto TEMPLATE (returns ``T_match``). The fine peers come in two forms,
as vgr does: "cold" (both clouds raw on every call) and "warm" (:class:`WarmPeers`: the template
preprocessed once, as vgr's stage prepares its template once at set-up; each call then prepares
only the current capture).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import small_gicp
from kiss_icp.mapping import VoxelHashMap
from kiss_icp.registration import Registration

reg = o3d.pipelines.registration

VOXEL_M = 0.002
MAX_CORRESPONDENCE_M = 0.01
MAX_ITERATIONS = 64
ROTATION_EPS_RAD = 1e-6
TRANSLATION_EPS_M = 1e-7


#: the settings every small_gicp GICP call here uses
GICP = {
    "registration_type": "GICP",
    "max_correspondence_distance": MAX_CORRESPONDENCE_M,
    "num_threads": 1,
    "max_iterations": MAX_ITERATIONS,
    "rotation_epsilon": ROTATION_EPS_RAD,
    "translation_epsilon": TRANSLATION_EPS_M,
}


def small_gicp_gicp(current: np.ndarray, template: np.ndarray, T_init: np.ndarray) -> np.ndarray:
    res = small_gicp.align(template, current, init_T_target_source=T_init, downsampling_resolution=VOXEL_M, **GICP)
    return np.array(res.T_target_source)


def _o3d_cloud(points: np.ndarray, voxel: float, normal_k: int = 20) -> o3d.geometry.PointCloud:
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(normal_k))
    pcd.orient_normals_towards_camera_location(np.zeros(3))
    return pcd


def _o3d_point_to_plane(
    src: o3d.geometry.PointCloud, tgt: o3d.geometry.PointCloud, T_init: np.ndarray, max_correspondence_m: float
) -> np.ndarray:
    crit = reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=MAX_ITERATIONS)
    res = reg.registration_icp(src, tgt, max_correspondence_m, T_init, reg.TransformationEstimationPointToPlane(), crit)
    return np.array(res.transformation)


def open3d_point_to_plane(
    current: np.ndarray, template: np.ndarray, T_init: np.ndarray, max_correspondence_m: float = MAX_CORRESPONDENCE_M
) -> np.ndarray:
    src, tgt = _o3d_cloud(current, VOXEL_M), _o3d_cloud(template, VOXEL_M)
    return _o3d_point_to_plane(src, tgt, T_init, max_correspondence_m)


def _kiss_map(points: np.ndarray) -> VoxelHashMap:
    vmap = VoxelHashMap(voxel_size=MAX_CORRESPONDENCE_M, max_distance=1e6, max_points_per_voxel=20)
    vmap.add_points(points)
    return vmap


def _kiss_align(current: np.ndarray, vmap: VoxelHashMap, T_init: np.ndarray) -> np.ndarray:
    src = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(current)).voxel_down_sample(VOXEL_M).points)
    registration = Registration(
        max_num_iterations=MAX_ITERATIONS, convergence_criterion=TRANSLATION_EPS_M, max_num_threads=1
    )
    return np.array(
        registration.align_points_to_map(
            points=src,
            voxel_map=vmap,
            initial_guess=T_init,
            max_correspondance_distance=MAX_CORRESPONDENCE_M,
            kernel=MAX_CORRESPONDENCE_M / 3.0,
        )
    )


def kiss_icp(current: np.ndarray, template: np.ndarray, T_init: np.ndarray) -> np.ndarray:
    down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(template)).voxel_down_sample(VOXEL_M)
    return _kiss_align(current, _kiss_map(np.asarray(down.points)), T_init)


class WarmPeers:
    """The fine peers with the template preprocessed once (the peers' own preprocessing, kept)."""

    def __init__(self, template: np.ndarray) -> None:
        self.sg_target, self.sg_tree = small_gicp.preprocess_points(
            template, downsampling_resolution=VOXEL_M, num_neighbors=10, num_threads=1
        )
        self.o3d_target = _o3d_cloud(template, VOXEL_M)
        self.kiss_map = _kiss_map(np.asarray(self.o3d_target.points))

    def small_gicp_gicp(self, current: np.ndarray, T_init: np.ndarray) -> np.ndarray:
        source, _ = small_gicp.preprocess_points(
            current, downsampling_resolution=VOXEL_M, num_neighbors=10, num_threads=1
        )
        res = small_gicp.align(self.sg_target, source, self.sg_tree, init_T_target_source=T_init, **GICP)
        return np.array(res.T_target_source)

    def open3d_point_to_plane(self, current: np.ndarray, T_init: np.ndarray) -> np.ndarray:
        return _o3d_point_to_plane(_o3d_cloud(current, VOXEL_M), self.o3d_target, T_init, MAX_CORRESPONDENCE_M)

    def kiss_icp(self, current: np.ndarray, T_init: np.ndarray) -> np.ndarray:
        return _kiss_align(current, self.kiss_map, T_init)


def open3d_fpfh_ransac(current: np.ndarray, template: np.ndarray, voxel: float, seed: int) -> np.ndarray:
    src, tgt = _o3d_cloud(current, voxel), _o3d_cloud(template, voxel)
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100)
    f_src, f_tgt = reg.compute_fpfh_feature(src, param), reg.compute_fpfh_feature(tgt, param)
    dist = 1.5 * voxel
    previous, level = o3d.utility.get_max_threads(), o3d.utility.get_verbosity_level()
    o3d.utility.set_max_threads(1)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    o3d.utility.random.seed(seed)
    try:
        res = reg.registration_ransac_based_on_feature_matching(
            src,
            tgt,
            f_src,
            f_tgt,
            True,
            dist,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
            reg.RANSACConvergenceCriteria(100000, 0.999),
        )
    finally:
        o3d.utility.set_max_threads(previous)
        o3d.utility.set_verbosity_level(level)
    return np.array(res.transformation)


def paper_baseline(current: np.ndarray, template: np.ndarray, coarse_voxel: float, seed: int) -> np.ndarray:
    """Seed 004's RANSAC + ICP: FPFH/RANSAC on ``coarse_voxel`` clouds, then point-to-plane ICP at
    the fine voxel with correspondences up to twice the coarse voxel."""
    T = open3d_fpfh_ransac(current, template, coarse_voxel, seed)
    return open3d_point_to_plane(current, template, T, max_correspondence_m=2.0 * coarse_voxel)
