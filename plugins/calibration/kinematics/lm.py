"""Levenberg-Marquardt with step limiting and a per-iteration history (for the convergence plot).

scipy's ``least_squares`` offers LM (MINPACK) but neither a step-length cap in physical units nor the
iteration history the calibration report shows, so this small loop is kept here. It minimises
``0.5 |r(x)|^2`` for residuals ``r`` (already whitened by the caller) given ``r`` and ``J = dr/dx``:

* scaled damping ``(J^T J + lambda diag(D^2)) dx = -J^T r`` with ``D`` the running maximum of the
  Jacobian column norms (MINPACK's scaling), lambda updated by Nielsen's gain-ratio rule;
* step limiting, as seed 003 asks: a step may not change the predictions by more than
  ``max(max_step, |r|)`` (``|J dx|``, in the units of the residuals) in one iteration;
* convergence when the full Gauss-Newton step would lower the cost by less than ``gn_tol`` (absolute;
  with whitened residuals the cost is half a chi-square, so 1e-9 is far below any statistical
  meaning). A relative-decrease test is not used: heavily damped steps along weakly identifiable
  directions decrease the cost very little while still far from the minimum, and stopping there
  leaves the estimate biased towards the start.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass
class LMResult:
    x: F64
    cost: float
    iterations: int
    converged: bool
    message: str
    history: list[dict] = field(default_factory=list)  # per iteration: cost, step_norm, lambda


def levenberg_marquardt(
    fun: Callable[[F64], tuple[F64, F64]],
    x0: F64,
    *,
    max_iterations: int = 50,
    max_step: float = 1.0,
    gn_tol: float = 1e-9,
    lambda0: float = 1e-4,
) -> LMResult:
    """Minimise ``0.5 |r|^2`` where ``fun(x) -> (r, J)``. See the module docstring."""
    x = np.asarray(x0, dtype=float).copy()
    r, J = fun(x)
    cost = 0.5 * float(r @ r)
    D = np.linalg.norm(J, axis=0)
    D[D == 0] = 1.0
    lam, nu = lambda0, 2.0
    history = [{"iteration": 0, "cost": cost, "step_norm": 0.0, "lambda": lam}]
    for it in range(1, max_iterations + 1):
        g = J.T @ r
        A = J.T @ J
        dx_gn, *_ = np.linalg.lstsq(J, -r, rcond=None)
        if 0.5 * float(np.sum((J @ dx_gn) ** 2)) <= gn_tol:
            return LMResult(x, cost, it - 1, True, "converged", history)
        D = np.maximum(D, np.linalg.norm(J, axis=0))
        accepted = False
        for _ in range(30):
            try:
                dx = -np.linalg.solve(A + lam * np.diag(D**2), g)
            except np.linalg.LinAlgError:
                lam *= nu
                nu *= 2
                continue
            change = float(np.linalg.norm(J @ dx))
            limit = max(max_step, float(np.linalg.norm(r)))
            if change > limit:
                dx *= limit / change
            step = float(np.linalg.norm(D * dx))
            r_new, J_new = fun(x + dx)
            cost_new = 0.5 * float(r_new @ r_new)
            predicted = -(g @ dx) - 0.5 * float(dx @ A @ dx)
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if rho > 0 and np.isfinite(cost_new):
                accepted = True
                break
            lam *= nu
            nu *= 2
        if not accepted:
            return LMResult(x, cost, it, False, "no step reduces the cost (lambda grew without success)", history)
        x = x + dx
        r, J, cost = r_new, J_new, cost_new
        lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        nu = 2.0
        history.append({"iteration": it, "cost": cost, "step_norm": step, "lambda": lam})
    return LMResult(x, cost, max_iterations, False, f"no convergence in {max_iterations} iterations", history)
