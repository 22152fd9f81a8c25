"""Estimating the measurement noise from the data when no noise specification is given.

The noise is the residual scale of the *most flexible* model the catalog allows: the baseline
calibration plus every testable candidate's regressor columns at once (every grid point of shape
parameters), fitted linearly. This is the full-model variance estimate of Mallows' Cp: unbiased for
the noise when the true gap lies in the span of the catalog, an *over*-estimate otherwise (so an
effect outside the catalog can then hide in the noise: the report says the noise was estimated).
"""

from __future__ import annotations

import numpy as np

from plugins.model_gap.core.interfaces import Candidate, GapInputError, GapProblem, Linearisation
from plugins.model_gap.core.sparse import sparse_library


def estimate_noise_scale(
    lin: Linearisation, candidates: list[Candidate], problem: GapProblem, *, min_dof: int = 30
) -> tuple[float, int]:
    """``(scale, dof)``: the factor by which ``lin.sigma`` must be multiplied to match the data's noise.

    Raises :class:`GapInputError` when fewer than ``min_dof`` residual degrees of freedom remain
    (too few samples for the catalog: give the noise explicitly).
    """
    Theta, y, _ = sparse_library(lin, candidates, problem)
    M = y.size
    rank_a = int(np.linalg.matrix_rank(lin.jacobian.reshape(M, -1))) if lin.jacobian.shape[2] else 0
    if Theta.shape[1]:
        U, s, _ = np.linalg.svd(Theta, full_matrices=False)
        U = U[:, s > 1e-8 * s[0]]
        r = y - U @ (U.T @ y)
        rank_t = U.shape[1]
    else:
        r, rank_t = y, 0
    dof = M - rank_a - rank_t
    if dof < min_dof:
        raise GapInputError(
            f"cannot estimate the noise from {lin.n_samples} samples ({dof} residual degrees of freedom after "
            f"fitting every candidate at once, need {min_dof}): give the noise (--noise-mm) or more samples"
        )
    return float(np.sqrt(float(r @ r) / dof)), dof
