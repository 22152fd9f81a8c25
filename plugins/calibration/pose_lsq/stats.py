"""Covariance, identifiability and residual tests of a whitened least-squares problem.

Every function takes the *whitened* Jacobian ``J`` (rows divided by their noise standard deviation,
so that the residual vector has unit covariance at the truth). Then ``J^T J`` is the Fisher
information, its (pseudo-)inverse the covariance of the estimate (and, evaluated at the truth, the
Cramér–Rao bound), and ``sum(r**2)`` is chi-square distributed with ``m - rank`` degrees of freedom.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

F64 = NDArray[np.float64]


def marginal_covariance(J: ArrayLike, n_keep: int | None = None, *, rel_tol: float = 1e-10) -> tuple[F64, int]:
    """Covariance of the first *n_keep* parameters (others are nuisance) and the rank of J.

    The columns are equilibrated (divided by their norms) before the SVD so that parameters in
    metres and radians are compared fairly; singular values below ``rel_tol * s_max`` are treated as
    zero (pseudo-inverse). A rank below the number of columns means some combination is not
    determined; its variance is then *not* represented (callers must report the rank deficiency).
    """
    J = np.asarray(J, dtype=float)
    n = J.shape[1]
    n_keep = n if n_keep is None else n_keep
    norms = np.linalg.norm(J, axis=0)
    scales = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 1.0)
    _, s, Vt = np.linalg.svd(J * scales, full_matrices=False)
    keep = s > rel_tol * (s[0] if s.size else 1.0)
    V = Vt[keep].T / s[keep]
    cov_scaled = V @ V.T
    cov = cov_scaled * np.outer(scales, scales)
    return cov[:n_keep, :n_keep], int(np.count_nonzero(keep))


@dataclass
class Identifiability:
    """Which parameter combinations a design determines (structural, noise-free analysis)."""

    rank: int
    n_params: int
    singular_values: F64
    null_space: F64  # (k, n) unit vectors in the scaled coordinates, k = n_params - rank
    descriptions: list[str] = field(default_factory=list)

    @property
    def full_rank(self) -> bool:
        return self.rank == self.n_params


def analyse_identifiability(
    J: ArrayLike,
    names: Sequence[str],
    scales: ArrayLike,
    *,
    J_nuisance: ArrayLike | None = None,
    rel_tol: float = 1e-7,
) -> Identifiability:
    """Rank and null space of the whitened design Jacobian *J* (columns = *names*).

    *scales* are typical magnitudes of each parameter (e.g. 1e-3 m, 1e-3 rad) so that the singular
    values compare like with like. Columns of *J_nuisance* (unknowns without prior, e.g. a free
    tool orientation) are projected out first: only what the data say about *names* remains.
    Each null-space vector is described by its dominant parameters, e.g.
    ``"0.71*T_base_desktop.vx - 0.71*T_tracker_tcp.vy"``.
    """
    J = np.asarray(J, dtype=float)
    if J_nuisance is not None:
        Jn = np.asarray(J_nuisance, dtype=float)
        if Jn.size:
            Q, sn, _ = np.linalg.svd(Jn, full_matrices=False)
            Q = Q[:, sn > rel_tol * max(sn[0], 1e-300)]
            J = J - Q @ (Q.T @ J)
    sc = np.asarray(scales, dtype=float)
    _, s, Vt = np.linalg.svd(J * sc, full_matrices=True)
    n = J.shape[1]
    s_full = np.zeros(n)
    s_full[: s.size] = s
    tol = rel_tol * (s_full[0] if s_full[0] > 0 else 1.0)
    rank = int(np.count_nonzero(s_full > tol))
    null = Vt[rank:]
    descriptions = []
    for v in null:
        order = np.argsort(-np.abs(v))
        terms = [f"{v[i]:+.2f}*{names[i]}" for i in order if abs(v[i]) >= 0.1]
        descriptions.append(" ".join(terms))
    return Identifiability(rank, n, s_full, null, descriptions)


def chi2_consistency(sum_sq: float, dof: int) -> tuple[float, float]:
    """(chi2 / dof, upper-tail p-value) of a whitened residual sum of squares; (nan, 1) when dof <= 0."""
    if dof <= 0:
        return float("nan"), 1.0
    return float(sum_sq / dof), float(chi2.sf(sum_sq, dof))


def studentised_block_tests(
    J: ArrayLike, r: ArrayLike, blocks: Sequence[ArrayLike], *, rel_tol: float = 1e-10
) -> tuple[F64, NDArray[np.int_], F64]:
    """Per-sample outlier test: statistic, degrees of freedom and p-value of each row *block*.

    Under the linearised model the whitened residuals are ``r = (I - H) e`` with the hat matrix
    ``H = J J^+``; the block statistic ``r_b^T (I - H)_bb^+ r_b`` is chi-square with
    ``rank((I - H)_bb)`` degrees of freedom when sample b is not an outlier. Blocks whose residual
    is fully absorbed by the fit (high leverage, dof 0) get statistic 0 and p-value 1: they cannot
    be tested, which the callers report.
    """
    J = np.asarray(J, dtype=float)
    r = np.asarray(r, dtype=float)
    U, s, _ = np.linalg.svd(J, full_matrices=False)
    U = U[:, s > rel_tol * (s[0] if s.size else 1.0)]
    stats = np.zeros(len(blocks))
    dofs = np.zeros(len(blocks), dtype=int)
    pvals = np.ones(len(blocks))
    for k, idx in enumerate(blocks):
        idx = np.asarray(idx)
        Ub = U[idx]
        M = np.eye(idx.size) - Ub @ Ub.T
        w, V = np.linalg.eigh(M)
        good = w > 1e-6
        dofs[k] = int(np.count_nonzero(good))
        if dofs[k] == 0:
            continue
        proj = V[:, good].T @ r[idx]
        stats[k] = float(np.sum(proj**2 / w[good]))
        pvals[k] = float(chi2.sf(stats[k], dofs[k]))
    return stats, dofs, pvals


def robust_variance_factor(stats: ArrayLike, dofs: ArrayLike) -> float:
    """Median-based estimate of how much larger the residual variance is than the noise model says.

    ``median(stat_b) / median(chi2(dof_b))`` over testable blocks; insensitive to a minority of
    outliers (unlike chi2/dof), so outlier tests stay meaningful when the noise model is too
    optimistic. Returns 1.0 when nothing is testable.
    """
    st = np.asarray(stats, dtype=float)
    df = np.asarray(dofs)
    ok = df > 0
    if not ok.any():
        return 1.0
    return float(np.median(st[ok]) / np.median(chi2.median(df[ok])))


def robust_block_pvalues(stats: ArrayLike, dofs: ArrayLike) -> tuple[F64, float]:
    """(p-values, factor) of the block tests of :func:`studentised_block_tests` against the data's
    own residual scale: the statistics divided by ``factor = max(1, robust_variance_factor)``, for
    when the noise model is too optimistic. Untestable blocks (dof 0) keep p-value 1."""
    factor = max(1.0, robust_variance_factor(stats, dofs))
    df = np.asarray(dofs)
    return np.where(df > 0, chi2.sf(np.asarray(stats, dtype=float) / factor, np.maximum(df, 1)), 1.0), factor
