"""Heavy-tailed noise in the outlier test: a multivariate-t tail fitted to the samples' costs.

With the noise estimated, ``ml`` flags a sample when its studentized cost ``s_i^2`` (chi-square(6)
for Gaussian noise) exceeds Pope's bound ``T0 = 6 F(6, nu_r)`` at ``outlier_quantile`` (Pope 1976,
*The statistics of residuals and the detection of outliers*, NOAA TR NOS 65). Honest but
heavy-tailed noise (a detector that now and then misses by several sigma) puts far more than 0.1 %
of good samples beyond that bound: Student-t noise with 3 degrees of freedom, 5 %. This module
tests whether the costs show such a tail and, when they do, moves the bound out.

Model (Lange, Little & Taylor 1989, *Robust statistical modeling using the t distribution*, JASA
84: 881-896): a sample's 6-vector of whitened residuals is Gaussian with a variance that varies
from sample to sample (``tau nu / chi2_nu``), i.e. multivariate t with ``nu`` degrees of freedom
and dispersion ``tau``; then ``s_i^2 / tau ~ 6 F(6, nu)``, and ``nu -> inf`` is the Gaussian case
``s_i^2 / tau ~ chi2(6)``.

1. **Fit** (:func:`fit_tail`): ``(tau, nu)`` by maximum likelihood on the samples whose cost is
   at most ``T1 = TAIL_FIT_RANGE x T0``, with the likelihood truncated at ``T1`` (each density
   divided by the model's probability of ``s^2 <= T1``), so whatever lies beyond ``T1`` - gross
   outliers, at any fraction - has no say; ``nu`` on a grid of 2 ... 100, ``tau`` by Brent's
   search; the Gaussian model likewise with ``tau`` alone.
2. **Test**: the t model is taken when the likelihood ratio ``2 (l_t - l_gauss)`` exceeds the 5 %
   point of its null distribution (``nu = inf`` lies on the border of the parameter space: half
   chi-square(0), half chi-square(1); bound 2.71). Gaussian noise keeps Pope's bound ``T0`` in 95 %
   of the sets; in the others the bound moves out by at most the factor ``TAIL_FIT_RANGE`` (step
   3), which is why a liberal level costs little.
3. **Bound**: with a tail, ``tau 6 F(6, nu)`` at ``outlier_quantile``, kept within ``[T0, T1]``:
   the fitted tail is not extrapolated beyond the costs it was fitted on (with 40 samples a t tail
   cannot be told from gross errors out there; ``T1`` is 67 at ``T0`` = 22.5, an 8-sigma residual).

Measured (``benchmarks/handeye_streams.py``, 40 poses, 30 sets): docs/handeye.md, Results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import stats
from scipy.optimize import minimize_scalar

F64 = NDArray[np.float64]

__all__ = ["TAIL_FIT_RANGE", "TailFit", "fit_tail"]

DOF = 6  # residual dimension of one sample
TAIL_FIT_RANGE = 3.0  # T1 / T0: the costs the tail is fitted on, and the largest bound it may set
TAIL_TEST_LEVEL = 0.05  # level of the likelihood-ratio test of a tail against Gaussian noise
NU_GRID = (2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0, 17.0, 25.0, 40.0, 60.0, 100.0)
MIN_SAMPLES = 10  # fewer costs than this within T1: no tail is fitted


@dataclass(frozen=True)
class TailFit:
    """The outcome of :func:`fit_tail`: the bound to flag at, whether a tail was found, its degrees
    of freedom ``nu`` (inf: Gaussian) and dispersion ``tau``, and the likelihood ratio."""

    threshold: float
    heavy: bool
    nu: float = float("inf")
    tau: float = 1.0
    likelihood_ratio: float = 0.0


def _nll(y: F64, log_tau: float, nu: float, t1: float) -> float:
    """Negative log-likelihood of costs *y* (all <= *t1*) under ``tau 6 F(6, nu)`` (chi-square(6)
    for infinite *nu*) truncated at *t1*."""
    tau = float(np.exp(log_tau))
    z = y / tau
    if np.isinf(nu):
        logpdf, logcdf = stats.chi2.logpdf(z, DOF), float(stats.chi2.logcdf(t1 / tau, DOF))
    else:
        logpdf = stats.f.logpdf(z / DOF, DOF, nu) - np.log(DOF)
        logcdf = float(stats.f.logcdf(t1 / tau / DOF, DOF, nu))
    return -float(np.sum(logpdf) - len(y) * (np.log(tau) + logcdf))


def _best_tau(y: F64, nu: float, t1: float) -> tuple[float, float]:
    """The dispersion maximising the truncated likelihood at *nu*: (nll, log tau)."""
    res = minimize_scalar(lambda a: _nll(y, a, nu, t1), bounds=(-4.0, 4.0), method="bounded", options={"xatol": 1e-4})
    return float(res.fun), float(res.x)


def fit_tail(stud: F64, t0: float, quantile: float) -> TailFit:
    """The outlier bound for studentized costs *stud* given Pope's Gaussian bound *t0* at
    *quantile* (module docstring): *t0* unless the costs show a t tail."""
    t1 = TAIL_FIT_RANGE * t0
    y = np.asarray(stud, float)
    y = y[(y > 0) & (y <= t1)]
    if len(y) < MIN_SAMPLES:
        return TailFit(t0, False)
    nll_gauss, _ = _best_tau(y, float("inf"), t1)
    nll, log_tau, nu = min((*_best_tau(y, nu, t1), nu) for nu in NU_GRID)
    lr = max(2.0 * (nll_gauss - nll), 0.0)
    if lr <= float(stats.chi2.ppf(1.0 - 2.0 * TAIL_TEST_LEVEL, 1)):
        return TailFit(t0, False, likelihood_ratio=lr)
    tau = float(np.exp(log_tau))
    bound = tau * DOF * float(stats.f.ppf(quantile, DOF, nu))
    return TailFit(float(np.clip(bound, t0, t1)), True, nu, tau, lr)
