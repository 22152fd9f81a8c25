"""Coarse hypotheses from FPFH features + RANSAC (Open3D), seeded and single-threaded.

Open3D's RANSAC draws from its global generator and its result depends on the TBB thread count, so
each run reseeds and limits Open3D to one thread (see ``determinism.py``). Several runs with
consecutive seeds give several hypotheses; the global matcher refines and ranks them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from plugins.registration.determinism import open3d_seeded, open3d_threads
from plugins.registration.preprocess import PreparedCloud

reg = o3d.pipelines.registration


@dataclass(frozen=True)
class FpfhParams:
    """FPFH + RANSAC settings; distances are multiples of the coarse cloud's resolution ``res``.

    Feature radius ``feature_radius_factor * res`` (at most ``max_nn`` neighbours); RANSAC inlier
    distance ``distance_factor * res``; Open3D's edge-length checker with ``edge_length_ratio``;
    ``runs`` independent RANSAC runs with seeds ``seed, seed + 1, ...``.
    """

    feature_radius_factor: float = 5.0
    max_nn: int = 100
    distance_factor: float = 1.5
    edge_length_ratio: float = 0.9
    mutual_filter: bool = True
    max_iterations: int = 100_000
    confidence: float = 0.999
    runs: int = 1


def fpfh_features(cloud: PreparedCloud, radius_m: float, max_nn: int, num_threads: int = 1) -> reg.Feature:
    """FPFH descriptors of the cloud's points (normals from :meth:`PreparedCloud.open3d`), cached."""
    key = ("fpfh", radius_m, max_nn)
    if key not in cloud._cache:
        with open3d_threads(num_threads):
            cloud._cache[key] = reg.compute_fpfh_feature(
                cloud.open3d(), o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_nn)
            )
    return cloud._cache[key]


def fpfh_ransac_hypotheses(
    current: PreparedCloud,
    template: PreparedCloud,
    params: FpfhParams,
    *,
    seed: int,
    num_threads: int = 1,
) -> list[tuple[np.ndarray, str]]:
    """``params.runs`` RANSAC estimates of ``T_match`` (current -> template) with their labels."""
    res = max(template.resolution(), current.resolution())
    radius = params.feature_radius_factor * res
    f_cur = fpfh_features(current, radius, params.max_nn, num_threads)
    f_tmp = fpfh_features(template, radius, params.max_nn, num_threads)
    dist = params.distance_factor * res
    checkers = [
        reg.CorrespondenceCheckerBasedOnEdgeLength(params.edge_length_ratio),
        reg.CorrespondenceCheckerBasedOnDistance(dist),
    ]
    out: list[tuple[np.ndarray, str]] = []
    level = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # silence "too few correspondences"
    try:
        for k in range(params.runs):
            with open3d_seeded(seed + k):
                r = reg.registration_ransac_based_on_feature_matching(
                    current.open3d(),
                    template.open3d(),
                    f_cur,
                    f_tmp,
                    params.mutual_filter,
                    dist,
                    reg.TransformationEstimationPointToPoint(False),
                    3,
                    checkers,
                    reg.RANSACConvergenceCriteria(params.max_iterations, params.confidence),
                )
            T = np.array(r.transformation)
            if np.all(np.isfinite(T)) and r.fitness > 0:
                out.append((T, f"fpfh_ransac:seed={seed + k}"))
    finally:
        o3d.utility.set_verbosity_level(level)
    return out
