"""How well a candidate ``T_match`` explains the current cloud by the template (one scoring rule for
every stage, so hypotheses from different generators are comparable).

* ``score``: truncated mean nearest-neighbour distance (m) of the current points mapped into the
  template, each distance capped at ``truncation_m`` (robust to partial overlap; lower is better);
* ``fitness``: fraction of current points with a template point within ``inlier_distance_m``;
* ``inlier_rmse``: RMS of those inlier distances (m);
* ``coverage`` (optional): fraction of template points with a mapped current point within
  ``inlier_distance_m`` (how much of the template is seen).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from engine import transforms as tf
from plugins.registration.preprocess import PreparedCloud


@dataclass
class AlignmentScore:
    score: float
    fitness: float
    inlier_rmse: float
    n_inliers: int
    inlier_source: np.ndarray  # indices into the current points
    inlier_target: np.ndarray  # indices into the template points
    coverage: float = float("nan")


def score_alignment(
    current_points: np.ndarray,
    template: PreparedCloud,
    T_match: np.ndarray,
    *,
    inlier_distance_m: float,
    truncation_m: float,
    num_threads: int = 1,
    with_coverage: bool = False,
) -> AlignmentScore:
    """Score ``T_match`` (see module docstring); ``current_points`` are (N, 3) in the current frame."""
    mapped = tf.transform_points(T_match, current_points)
    d, idx = template.nearest(mapped, num_threads=num_threads)
    inl = d <= inlier_distance_m
    n_in = int(np.count_nonzero(inl))
    score = float(np.mean(np.minimum(d, truncation_m))) if d.size else float("inf")
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if n_in else float("nan")
    coverage = float("nan")
    if with_coverage:
        dt, _ = cKDTree(mapped).query(template.points, k=1, workers=num_threads)
        coverage = float(np.mean(dt <= inlier_distance_m))
    return AlignmentScore(
        score=score,
        fitness=n_in / max(d.size, 1),
        inlier_rmse=rmse,
        n_inliers=n_in,
        inlier_source=np.flatnonzero(inl),
        inlier_target=idx[inl],
        coverage=coverage,
    )
