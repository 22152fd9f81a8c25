"""Fits of one depth model (a set of catalog effects) to the captures' pixels, the gross-error
screen, and the noise the residuals show.

**The screen** (:func:`screen`). Mixed pixels at the target's edges and flying pixels are range
errors of centimetres; they would dominate any least-squares score. The richest model (every
testable catalog effect, so that an effect in the catalog is not taken for outliers) is fitted with
``scipy.optimize.least_squares`` and a soft-L1 loss on residuals divided by the noise ``sigma``: the
law ``a + b z^2`` fitted to the robust scale (1.4826 x the median absolute residual) of the
residuals in bins of depth (:func:`sigma_law`), re-estimated once from the first robust fit (the
first uses each capture's robust scale). The screen always uses this estimate, never a stated
noise: a stated law that is too optimistic would flag good pixels by the thousand (and hide the
gap the noise check should find), a pessimistic one would keep flying pixels. A pixel is a gross
error when ``|residual| > k sigma`` with ``k`` the Gaussian quantile at which a capture set of N
good pixels loses any with probability ``outlier_alpha`` (``k = Phi^-1(1 - alpha / 2N)``: ~5.3 sigma
for 1e5 pixels at 0.01). Flagged pixels are left out of everything after and reported. The noise
the fits after the screen weight by is the stated ``sigma(z)`` when given, else the law refitted to
the pixels left.

**The fits** (:func:`fit_model`) on the pixels left are weighted linear least squares
(``numpy.linalg.lstsq``; weights ``1 / sigma``): the maximum-likelihood estimate under the Gaussian
noise the screen leaves, exact in one step because every effect is linear. With the plane fitted
per capture (``Pixels.jac``), each capture's three plane columns are eliminated first
(:func:`.data.project_out`: Frisch-Waugh-Lovell), which is the same estimate as the joint fit; a
capture's residuals under a model (:func:`residuals_under`) are those with its own plane refitted
with the effects held: for a capture the fit did not see, its held-out residuals.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from plugins.model_gap.depth.catalog import DepthEffect, feature_matrix
from plugins.model_gap.depth.data import Pixels, SigmaLaw, project_out

F64 = NDArray[np.float64]

MAX_ROBUST_PIXELS = 40_000  # the robust screen fits a random sample of this many pixels

__all__ = [
    "MAX_ROBUST_PIXELS",
    "DepthFit",
    "Screen",
    "capture_scale",
    "fit_model",
    "residuals_under",
    "screen",
    "sigma_law",
]


@dataclass(frozen=True, eq=False)
class DepthFit:
    """A fit of the model made of ``effects``: their coefficients ``theta`` (SI, in column order)."""

    effects: tuple[DepthEffect, ...]
    theta: F64

    def theta_of(self, effect: DepthEffect) -> F64:
        """The coefficients of *effect* (one of ``effects``)."""
        start = 0
        for e in self.effects:
            if e is effect or e.name == effect.name:
                return self.theta[start : start + e.n_params]
            start += e.n_params
        raise KeyError(effect.name)


def _columns(px: Pixels, effects: Sequence[DepthEffect], period: float) -> F64:
    return feature_matrix(effects, px.r_ref, px.x, px.y, period)


def fit_model(
    px: Pixels, train: NDArray[np.bool_], effects: Sequence[DepthEffect], weights: F64, period: float
) -> DepthFit:
    """The weighted least-squares fit of *effects* to the pixels in *train* (module docstring)."""
    effects = tuple(effects)
    if not effects:
        return DepthFit(effects, np.zeros(0))
    sub = px.take(train)
    w = weights[train]
    a = project_out(sub, _columns(sub, effects, period), w)
    y = project_out(sub, sub.residual, w)
    scale = np.sqrt(np.mean(a**2, axis=0))
    scale[scale == 0] = 1.0
    theta, *_ = np.linalg.lstsq(a * w[:, None] / scale, y * w, rcond=None)
    return DepthFit(effects, theta / scale)


def residuals_under(px: Pixels, fit: DepthFit, weights: F64, period: float) -> F64:
    """Every pixel's range residual (m) under *fit*, each capture's plane refitted (``target = "fit"``)."""
    e = px.residual - (_columns(px, fit.effects, period) @ fit.theta if fit.effects else 0.0)
    return project_out(px, e, weights)


def capture_scale(px: Pixels, residual: F64) -> F64:
    """Per capture, the robust scale 1.4826 x the median absolute residual (m), floored at 1 um."""
    out = np.zeros(px.n_captures)
    for k in range(px.n_captures):
        r = residual[px.capture == k]
        out[k] = 1.4826 * float(np.median(np.abs(r - np.median(r)))) if len(r) else 0.0
    return np.maximum(out, 1e-6)


def sigma_law(z: F64, residual: F64, bins: int = 12) -> SigmaLaw:
    """The noise law ``a + b z^2`` (a, b >= 0) fitted to the robust scale (1.4826 x MAD) of the
    residuals in *bins* quantile bins of the depth *z*: the shape of stereo, structured-light and ToF
    noise, estimated where the sensor's own is not stated."""
    from scipy.optimize import least_squares

    edges = np.quantile(z, np.linspace(0.0, 1.0, bins + 1))
    b = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, bins - 1)
    zc, sc, wt = [], [], []
    for i in range(bins):
        r = residual[b == i]
        if len(r) >= 10:
            zc.append(float(np.median(z[b == i])))
            sc.append(1.4826 * float(np.median(np.abs(r - np.median(r)))))
            wt.append(np.sqrt(len(r)))
    zc_, sc_, wt_ = np.asarray(zc), np.asarray(sc), np.asarray(wt)
    if len(zc_) < 2:
        return SigmaLaw(max(float(np.median(sc_)) if len(sc_) else 1e-6, 1e-6))
    fit = least_squares(
        lambda q: wt_ * (q[0] + q[1] * zc_**2 - sc_) / max(float(np.median(sc_)), 1e-9),
        [float(np.median(sc_)), 0.0],
        bounds=([0.0, 0.0], [np.inf, np.inf]),
    )
    return SigmaLaw(max(float(fit.x[0]), 1e-6), float(fit.x[1]))


@dataclass(frozen=True, eq=False)
class Screen:
    """The gross-error screen's outcome: the inlier mask, each pixel's noise sigma (m), the threshold."""

    inlier: NDArray[np.bool_]
    sigma: F64  # (n_pixels,) the fits' noise (m): the stated sigma(z), else the law estimated from the inliers
    threshold_sigma: float
    residual: F64  # of the robust fit (m)
    sigma_source: str  # "stated" | "estimated"
    alpha: float

    @property
    def n_flagged(self) -> int:
        return int(np.count_nonzero(~self.inlier))


def _robust_fit(px: Pixels, effects: Sequence[DepthEffect], sigma: F64, period: float) -> F64:
    """Residuals (m) of the soft-L1 fit of *effects* (and each capture's plane) to all pixels.

    The fit is ``scipy.optimize.least_squares`` (trust region, exact SVD steps: the design is rank
    deficient with the planes free, which the iterative LSMR solver converges on only slowly) on at
    most :data:`MAX_ROBUST_PIXELS` pixels drawn at random (seeded) from all captures; the residuals
    are those of every pixel under the fitted coefficients."""
    from scipy.optimize import least_squares

    y = px.residual
    a = _columns(px, effects, period)
    n_plane = 0 if px.jac is None else 3 * px.n_captures
    if a.shape[1] + n_plane == 0:
        return y
    n = len(y)
    pick = np.arange(n)
    if n > MAX_ROBUST_PIXELS:
        pick = np.sort(np.random.default_rng(0).choice(n, MAX_ROBUST_PIXELS, replace=False))
    design = a[pick]
    if px.jac is not None:
        planes = np.zeros((len(pick), n_plane))
        cols = 3 * px.capture[pick, None] + np.arange(3)
        np.put_along_axis(planes, cols, px.jac[pick], axis=1)
        design = np.hstack((design, planes))
    scaled = design / sigma[pick, None]
    col = np.sqrt(np.mean(scaled**2, axis=0))
    col[col == 0] = 1.0
    scaled /= col
    target = y[pick] / sigma[pick]
    sol = least_squares(
        lambda p: scaled @ p - target, np.zeros(scaled.shape[1]), jac=lambda p: scaled,
        loss="soft_l1", f_scale=2.0, method="trf", tr_solver="exact",
    )  # fmt: skip
    theta = sol.x / col
    e = y - a @ theta[: a.shape[1]]
    if px.jac is not None:
        q = theta[a.shape[1] :].reshape(px.n_captures, 3)
        e -= np.sum(px.jac * q[px.capture], axis=1)
    return e


def screen(px: Pixels, effects: Sequence[DepthEffect], stated: SigmaLaw | None, alpha: float, period: float) -> Screen:
    """The gross-error screen of the module docstring (``alpha = 0``: no pixel is flagged)."""
    from scipy.stats import norm

    sigma = capture_scale(px, project_out(px, px.residual))[px.capture]
    e = _robust_fit(px, effects, sigma, period)
    sigma = sigma_law(px.z_ref, e)(px.z_ref)
    e = _robust_fit(px, effects, sigma, period)
    sigma = sigma_law(px.z_ref, e)(px.z_ref)
    n = len(e)
    k = float(norm.isf(alpha / (2.0 * n))) if alpha > 0 else float("inf")
    inlier = np.abs(e) <= k * sigma
    if stated is not None:  # the fits weight by the sensor's own law
        sigma = stated(px.z_ref)
    else:  # the law of the good pixels (the gross errors inflate the MAD a little)
        sigma = sigma_law(px.z_ref[inlier], e[inlier])(px.z_ref)
    return Screen(inlier, sigma, k, e, "stated" if stated is not None else "estimated", alpha)
