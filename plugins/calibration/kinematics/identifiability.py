"""Identifiability analysis of a calibration Jacobian: which parameters the data can determine.

Columns are first scaled to unit norm (metres and radians become comparable). A Gram-Schmidt QR
*in the candidate order* (base, tool, joints from the base outwards; no pivoting, so the choice
among equivalent parameters is predictable) then keeps a parameter when its column has a
component of relative size ``> tol`` outside the span of the parameters kept before it (the
``|R_jj|`` of the QR); the others are not identifiable and are fixed at their current values. For each dropped
parameter the report names the kept parameters it is confounded with (least-squares coefficients of
its column on the kept ones). The singular values of the kept, scaled Jacobian give the
observability indices:

``O1 = (s_1 s_2 ... s_m)^(1/m) / sqrt(L)``  (Borm & Menq 1991; L = number of residuals)
``condition = s_1 / s_m``

Comparing with the same analysis on a rich random set of configurations tells *structural*
redundancy (no data can help) from *lack of excitation* (other poses would help).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass
class Identifiability:
    names: list[str]
    kept: list[str]
    dropped: list[str]
    confounded_with: dict[str, list[tuple[str, float]]] = field(default_factory=dict)
    r_diag: dict[str, float] = field(default_factory=dict)  # relative independent part of each column
    singular_values: F64 | None = None
    observability_o1: float = 0.0
    condition_number: float = np.inf

    @property
    def kept_index(self) -> list[int]:
        return [self.names.index(n) for n in self.kept]

    def describe_dropped(self) -> list[str]:
        out = []
        for n in self.dropped:
            partners = self.confounded_with.get(n, [])
            if partners:
                combo = " + ".join(f"{c:+.3g} {p}" for p, c in partners)
                out.append(f"{n} (acts like {combo})")
            else:
                out.append(f"{n} (no effect on the measurements)")
        return out


def analyse(J: F64, names: list[str], tol: float = 1e-6) -> Identifiability:
    """Identifiability of the columns of ``J`` (L x P), in the given order (see module docstring)."""
    J = np.asarray(J, dtype=float)
    norms = np.linalg.norm(J, axis=0)
    zero = norms <= 1e-14 * max(1.0, norms.max(initial=0.0))
    Js = np.where(zero, 0.0, J / np.where(zero, 1.0, norms))
    kept_idx: list[int] = []
    r_diag: dict[str, float] = {}
    basis = np.zeros((J.shape[0], 0))
    for j in range(J.shape[1]):
        if zero[j]:
            r_diag[names[j]] = 0.0
            continue
        col = Js[:, j]
        resid = col - basis @ (basis.T @ col) if basis.shape[1] else col
        resid = resid - (basis @ (basis.T @ resid) if basis.shape[1] else 0.0)  # re-orthogonalise
        rj = float(np.linalg.norm(resid))
        r_diag[names[j]] = rj
        if rj > tol:
            kept_idx.append(j)
            basis = np.column_stack([basis, resid / rj])
    if kept_idx:
        s = np.linalg.svd(Js[:, kept_idx], compute_uv=False)
        o1 = float(np.exp(np.mean(np.log(s))) / np.sqrt(J.shape[0])) if np.all(s > 0) else 0.0
        cond = float(s[0] / s[-1]) if s[-1] > 0 else np.inf
    else:
        s, o1, cond = np.zeros(0), 0.0, np.inf
    dropped = [names[j] for j in range(J.shape[1]) if j not in kept_idx]
    confounded: dict[str, list[tuple[str, float]]] = {}
    live = [names.index(n) for n in dropped if not zero[names.index(n)]]
    if kept_idx and live:
        coefs, *_ = np.linalg.lstsq(Js[:, kept_idx], Js[:, live], rcond=None)  # all dropped columns at once
        for col, j in enumerate(live):
            coef = coefs[:, col]
            # in physical units: dropped column = sum_k c_k * kept column_k
            c_phys = coef * norms[j] / norms[kept_idx]
            big = np.argsort(-np.abs(coef))[:4]
            confounded[names[j]] = [(names[kept_idx[k]], float(c_phys[k])) for k in big if abs(coef[k]) > 0.05]
    return Identifiability(
        names=list(names),
        kept=[names[j] for j in kept_idx],
        dropped=dropped,
        confounded_with=confounded,
        r_diag=r_diag,
        singular_values=s,
        observability_o1=o1,
        condition_number=cond,
    )
