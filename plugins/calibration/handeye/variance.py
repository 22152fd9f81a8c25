"""Confidence regions when the noise is estimated: Kenward-Roger for the hand-eye ML estimate.

When the noise is declared, the covariance ``C`` of the estimate is known and the 95 % confidence
region of ``k`` parameters is ``d^T C^-1 d <= chi2_k(0.95)``. When the noise is *estimated*, the
reported covariance is itself a random estimate. With a single variance factor estimated from ``nu``
redundant residuals, ``d^T C^-1 d / k`` follows Fisher's ``F(k, nu)`` exactly (linear Gaussian
model): the region is ``d^T C^-1 d <= k F_{k,nu}(0.95)``, wider than the chi-square one (for
``k = 6``: 13.3 at ``nu = 80``, 14.0 at ``nu = 40``, against 12.6).

The hand-eye solver estimates several variance components (robot/camera translation/rotation, or
one common camera factor of per-sample covariances; Förstner-Helmert, see ``ml``): the estimated
noise is ``f_g`` times the prior of group ``g``.
Two things then differ from the one-factor case, and Kenward & Roger (1997, Biometrics 53:983) treat
both for REML-type variance components, of which the converged Helmert estimate is one:

1. The covariance ``Phi = S^-1`` evaluated at the estimated ``f`` is biased low, and the estimate,
   weighted with estimated variances, scatters more than ``Phi`` says (Kackar-Harville). The
   adjusted covariance is ``Phi_A = Phi + 2 Lambda`` with
   ``Lambda = Phi [sum_g W_gg B_g - sum_gh W_gh B_g Phi B_h] Phi`` (full parameter space, whitened
   units), ``B_g = J^T E_g J`` the information carried by group ``g``'s residual rows and
   ``W = cov(f^) = 2 H^-1``, with Helmert's matrix ``H_gh = tr(R E_g R E_h)`` (``R`` the whitened
   residual projector, ``E_g`` the selector of group ``g``'s rows).
2. The statistic ``F* = lambda d^T Phi_A^-1 d / k`` follows ``F(k, m)`` approximately, with
   Kenward-Roger's denominator degrees of freedom ``m`` and scale ``lambda`` (close to 1) from
   ``A1 = sum W_gh tr(T C_g) tr(T C_h)`` and ``A2 = sum W_gh tr(T C_g T C_h)`` (``T`` the inverse of
   the block of ``Phi_A``, ``C_g`` the block of ``Phi B_g Phi``). For one variance factor this is
   exact: ``Lambda = 0``, ``m = nu``, ``lambda = 1``. ``m`` is close to Satterthwaite's
   ``2 k^2 / A1``: small when the block's uncertainty comes from a group with few redundant residuals
   or from two groups the data hardly separate (robot and camera translation noise).

So the region of a block of ``k`` parameters is ``d^T Phi_A^-1 d <= k F_{k,m}(level) / lambda``.
Groups kept at their prior (redundancy below 1) are known (no variance). Everything is computed
from the per-sample block structure (12 x 12 matrices, the nuisance robot poses eliminated: in the
(X, Y) block, ``Phi B_g Phi`` is ``S^-1 B~_g S^-1`` with ``B~_g`` from the projected Jacobian
``G~_i = Q_i G_i``, and ``Phi B_g Phi B_h Phi`` adds a per-sample term through the nuisance
projector ``P_i = I - Q_i``), never the ``(r n) x (r n)`` projector.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.handeye.ml_model import EivModel, EivState

F64 = NDArray[np.float64]

__all__ = ["KenwardRoger", "group_rows", "helmert_matrix", "kenward_roger", "kenward_roger_dof"]


def group_rows(model: EivModel) -> list[slice]:
    """Rows of each noise group within a sample's whitened residual: robot translation and rotation
    (when the robot is free), then the camera's translation and rotation, or each of its six axes
    when the model says ``camera_axes`` (a depth camera's or a PnP pose's noise is largest along
    the optical axis), or all six as one group when each sample has its own camera covariance
    (``EivModel.camera_per_sample``: one common factor of the given covariances)."""
    robot = [slice(0, 3), slice(3, 6)] if model.robot_free else []
    c0 = 6 if model.robot_free else 0
    if model.camera_per_sample:
        return [*robot, slice(c0, c0 + 6)]
    if model.camera_axes:
        return robot + [slice(c0 + k, c0 + k + 1) for k in range(6)]
    return [*robot, slice(c0, c0 + 3), slice(c0 + 3, c0 + 6)]


def _projected_blocks(model: EivModel, st: EivState, weights: F64) -> tuple[list[F64], list[F64], list[int]]:
    """Per used sample: ``Q_i`` (projector off the nuisance columns) and ``G~_i = Q_i G_i``."""
    assert st.J_glob is not None
    Qs, Gs, used = [], [], []
    r = model.rows_per_sample
    for i in np.flatnonzero(weights > 0):
        sw = np.sqrt(weights[i])
        G = st.J_glob[i] * sw
        if model.robot_free:
            assert st.J_nuis is not None
            N = st.J_nuis[i] * sw
            Q = np.eye(r) - N @ np.linalg.solve(N.T @ N, N.T)
        else:
            Q = np.eye(r)
        Qs.append(Q)
        Gs.append(Q @ G)
        used.append(int(i))
    return Qs, Gs, used


def helmert_matrix(model: EivModel, st: EivState, weights: F64) -> tuple[F64, list[F64], F64]:
    """Helmert's ``H`` (groups x groups), the group information parts ``B_g`` (12 x 12, summing to
    the Schur-complement information ``S``) and ``S`` itself, at state ``st``.

    ``sum_h H_gh`` is group ``g``'s redundancy ``tr(E_g R)``.
    """
    groups = group_rows(model)
    Qs, Gs, _ = _projected_blocks(model, st, weights)
    S = sum((G.T @ G for G in Gs), np.zeros((12, 12)))
    S_inv = np.linalg.pinv(S)
    B = [sum((G[g].T @ G[g] for G in Gs), np.zeros((12, 12))) for g in groups]
    m = len(groups)
    H = np.zeros((m, m))
    for Q, G in zip(Qs, Gs, strict=True):
        P = G @ S_inv @ G.T  # this sample's block of the hat part G~ S^-1 G~^T
        for a, ga in enumerate(groups):
            for b, gb in enumerate(groups):
                H[a, b] += np.sum(Q[ga, gb] ** 2) - 2.0 * np.sum(Q[ga, gb] * P[ga, gb])
    for a in range(m):
        for b in range(m):
            H[a, b] += float(np.trace(S_inv @ B[a] @ S_inv @ B[b]))
    return H, B, S


@dataclass(frozen=True)
class KenwardRoger:
    """Adjusted (X, Y) covariance (12 x 12, unscaled units) and, per requested block, the F
    distribution's denominator degrees of freedom ``dof`` and scale ``f_scale`` (``lambda``)."""

    covariance: F64
    dof: list[float]
    f_scale: list[float]


def kenward_roger_dof(T: F64, C: Sequence[F64], W: F64) -> tuple[float, float]:
    """Kenward-Roger ``(m, lambda)`` for a block: ``T`` the inverse of the block of the adjusted
    covariance, ``C[g]`` the block of ``Phi B_g Phi`` per noise group, ``W`` the covariance of the
    variance-component estimates. ``(inf, 1)`` when no variance is estimated."""
    k = T.shape[0]
    tr1 = np.array([np.trace(T @ Cg) for Cg in C])
    a1 = float(tr1 @ W @ tr1)
    a2 = float(sum(W[a, b] * np.trace(T @ C[a] @ T @ C[b]) for a in range(len(C)) for b in range(len(C))))
    if not a2 > 1e-12 * k:
        return float("inf"), 1.0
    b = (a1 + 6.0 * a2) / (2.0 * k)
    g = ((k + 1) * a1 - (k + 4) * a2) / ((k + 2) * a2)
    den = 3.0 * k + 2.0 * (1.0 - g)
    c1, c2, c3 = g / den, (k - g) / den, (k + 2 - g) / den
    e_star = 1.0 / (1.0 - a2 / k)
    v_star = (2.0 / k) * (1.0 + c1 * b) / ((1.0 - c2 * b) ** 2 * (1.0 - c3 * b))
    rho = v_star / (2.0 * e_star**2)
    if not (np.isfinite(rho) and k * rho > 1.0 and a2 < k):
        # outside the approximation's range (tiny redundancy): Satterthwaite's dof, no rescaling
        return max(2.0 * k * k / a1, 1.0) if a1 > 0 else float("inf"), 1.0
    m = 4.0 + (k + 2.0) / (k * rho - 1.0)
    return float(m), float(m / (e_star * (m - 2.0)))


def kenward_roger(
    model: EivModel,
    st: EivState,
    weights: F64,
    estimated: Sequence[bool] | NDArray[np.bool_],
    blocks: Sequence[slice],
) -> KenwardRoger:
    """Kenward-Roger adjusted covariance of (X, Y) and the F parameters of each block (docstring)."""
    est = np.asarray(estimated, dtype=bool)
    groups = group_rows(model)
    est = est[: len(groups)]
    Qs, Gs, _ = _projected_blocks(model, st, weights)
    H, B, S = helmert_matrix(model, st, weights)
    S_inv = np.linalg.pinv(S)
    if not np.any(est):
        return KenwardRoger(S_inv, [float("inf")] * len(blocks), [1.0] * len(blocks))
    m = len(groups)
    W = np.zeros((m, m))
    W[np.ix_(est, est)] = 2.0 * np.linalg.pinv(H[np.ix_(est, est)])
    SB = [S_inv @ Bg for Bg in B]
    C = [SBg @ S_inv for SBg in SB]  # (X, Y) block of Phi B_g Phi
    lam = np.zeros((12, 12))
    for a in range(m):
        lam += W[a, a] * C[a]
        for b in range(m):
            if W[a, b] != 0.0:
                lam -= W[a, b] * SB[a] @ C[b]
    r = model.rows_per_sample
    for Q, G in zip(Qs, Gs, strict=True):
        P = np.eye(r) - Q  # projector onto this sample's nuisance columns (zero for exact robot poses)
        if not np.any(P):
            continue
        U = G @ S_inv
        for a, ga in enumerate(groups):
            for b, gb in enumerate(groups):
                if W[a, b] != 0.0:
                    lam -= W[a, b] * U[ga].T @ P[ga, gb] @ U[gb]
    phi_a = S_inv + lam + lam.T  # Phi + 2 Lambda, symmetrised
    dofs, scales = [], []
    for blk in blocks:
        T = np.linalg.pinv(phi_a[blk, blk])
        dof, scale = kenward_roger_dof(T, [Cg[blk, blk] for Cg in C], W)
        dofs.append(dof)
        scales.append(scale)
    return KenwardRoger(phi_a, dofs, scales)
