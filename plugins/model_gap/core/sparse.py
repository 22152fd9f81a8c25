"""Sparse-regression baseline for the model-gap benchmark: STLSQ over the effects' linearised regressors.

This is what a SINDy-style method (PySINDy's ``STLSQ`` optimiser: sequentially thresholded ridge
regression, Brunton, Proctor & Kutz, PNAS 2016) does with the same library vgr tests: every candidate
effect's whitened regressor columns (every grid point for effects with a time constant) with the
baseline calibration's span projected out, columns scaled to unit norm (``normalize_columns``),
regressed on the whitened residual of the calibrated model; coefficients below the threshold are
zeroed and the rest refitted until the support is stable. An effect is "named" when any of its
columns keeps a non-zero coefficient. It is the comparison point of ``benchmarks/gap.py``, not part
of the workflow. Written here (numpy, ~30 lines) rather than depending on pysindy: the optimiser is
the whole method, and the library must be vgr's for the comparison to be like for like.
"""

from __future__ import annotations

import numpy as np

from plugins.model_gap.core.interfaces import F64, Candidate, GapProblem, Linearisation
from plugins.model_gap.core.selection import _basis, _perp


def _ridge(X: F64, y: F64, alpha: float) -> F64:
    if alpha > 0:
        return np.linalg.solve(X.T @ X + alpha * np.eye(X.shape[1]), X.T @ y)
    return np.linalg.lstsq(X, y, rcond=None)[0]


def stlsq(Theta: F64, y: F64, threshold: float, alpha: float = 0.0, max_iter: int = 25) -> F64:
    """Sequentially thresholded least squares (PySINDy's STLSQ) for ``y ~ Theta @ coef``."""
    coef = _ridge(Theta, y, alpha)
    support = np.abs(coef) >= threshold
    for _ in range(max_iter):
        coef = np.zeros(Theta.shape[1])
        if support.any():
            coef[support] = _ridge(Theta[:, support], y, alpha)
        new = np.abs(coef) >= threshold
        if np.array_equal(new, support):
            break
        support = new
    coef[~support] = 0.0
    return coef


def sparse_library(
    lin: Linearisation, candidates: list[Candidate], problem: GapProblem, absorbed_tol: float = 1e-4
) -> tuple[F64, F64, list[tuple[str, str]]]:
    """``(Theta, y, owner)``: unit-norm library columns after calibration, target, candidate per column."""
    M = lin.residual.size
    A = lin.jacobian.reshape(M, -1)
    Q = _basis(A)
    y = _perp(Q, lin.residual.reshape(-1))
    cols, owner = [], []
    for c in candidates:
        if c.unavailable:
            continue
        for d in c.designs(problem):
            B = d.columns.reshape(M, -1)
            norms = np.linalg.norm(B, axis=0)
            Bp = _perp(Q, B)
            for j in range(B.shape[1]):
                n = np.linalg.norm(Bp[:, j])
                if norms[j] > 0 and n > absorbed_tol * norms[j]:
                    cols.append(Bp[:, j] / n)
                    owner.append((c.name, c.where))
    Theta = np.column_stack(cols) if cols else np.zeros((M, 0))
    return Theta, y, owner


def stlsq_named(Theta: F64, y: F64, owner: list[tuple[str, str]], threshold: float, alpha: float = 0.0) -> set:
    """The candidates (name, where) STLSQ keeps at ``threshold``."""
    if Theta.shape[1] == 0:
        return set()
    coef = stlsq(Theta, y, threshold, alpha)
    return {owner[j] for j in np.flatnonzero(coef)}
