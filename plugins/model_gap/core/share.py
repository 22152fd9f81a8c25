"""The share rule: when structure is left at the end, a catalog effect stays only if it explains a stated
share of what is left.

Forward selection names the candidate that takes the largest decisive piece of the gap. When the gap
is outside the catalog, a candidate that shares part of its signature can take a small piece (an
``encoder_eccentricity@joint6`` taking 14 % of a joint-6 error driven by joint 5's angle) and would be
reported as the cause. So when the end test (:mod:`.end_test`, :mod:`.structure`) finds structure
left after the last round, every added term that is not geometric is scored against what is left:

* the noise reference ``s^2`` (whitened) is, in this order, the replicate measurements' pure-error
  variance, the stated noise (``1``; or less when the residuals are below it), else the residual
  variance once the significant structure designs (at most five) are fitted on top of the model;
* what is left: ``left = max(RSS - dof s^2, 0)`` (``RSS`` and ``dof = M - rank A`` of the final model);
* what effect ``e`` explains: ``gain_e = max(RSS_without_e - RSS - k_e s^2, 0)`` (the rest refitted
  without it, linearised; ``k_e s^2`` is what noise alone would give ``k_e`` parameters);
* its **share of what is left without it**: ``gain_e / (gain_e + left)``.

A term is kept only when its share is at least ``min_share`` (default 0.3; in the benchmark the
stand-ins for out-of-catalog errors took 14-22 % and a real effect next to an out-of-catalog one of
the same size about 50 %) **and** it is still decisive over the structure left: with the significant
structure designs (at most five; not the design of the term's own joint and regressor, e.g.
``joint2~tau2`` for a joint-2 compliance, which contains the term) fitted too, the term still gains
the naming margin in BIC (``M ln(RSS_without / RSS_with) - k ln M >= 10``). The second condition
catches a stand-in that takes most of an out-of-catalog error's signature (an
``encoder_eccentricity@joint2`` for joint 3's error driven by joint 2's angle, the two axes
parallel): the structure design that found the rest explains it as well. A term failing either is
taken out again and reported under ``dropped``; the shares and gains of every term are reported. The
verdict stays ``unexplained`` (structure is left).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from plugins.model_gap.core.end_test import direction_designs
from plugins.model_gap.core.interfaces import Feature, Linearisation
from plugins.model_gap.core.selection import _basis, _perp
from plugins.model_gap.core.structure import StructureTest, _designs

DEFAULT_MIN_SHARE = 0.3


@dataclass
class ShareCheck:
    """The share rule's figures (module docstring); shares keyed by the term's label."""

    min_share: float
    reference: str  # replicate measurements | stated noise | the structure designs
    noise_variance: float  # s^2, whitened
    left: float  # whitened sum of squares left above the noise by the final model (before any drop)
    left_fraction: float  # left / RSS
    margin: float = 10.0
    shares: dict[str, float] = field(default_factory=dict)
    gain_given_structure: dict[str, float] = field(default_factory=dict)  # BIC gain with the structure fitted
    dropped: list[tuple[str, float]] = field(default_factory=list)

    def kept(self, label: str) -> bool:
        return self.shares[label] >= self.min_share and self.gain_given_structure.get(label, np.inf) >= self.margin

    def why(self, label: str) -> str:
        """``a@x (14 % of what is left, BIC gain 3.2 given the structure left)``."""
        return (
            f"{label} ({self.shares[label]:.0%} of what is left without it, {self.min_share:.0%} required; BIC gain "
            f"{self.gain_given_structure.get(label, float('nan')):.1f} with the structure left fitted, "
            f"{self.margin:g} required)"
        )


def structure_union(
    lin: Linearisation, st: StructureTest, features: list[Feature], directions, exclude: tuple[str, ...] = ()
) -> np.ndarray | None:
    """``(M, k)`` whitened: the significant structure designs (at most five, not those in ``exclude``) side
    by side, or None."""
    skip = ("replicates", "stated_noise", *exclude)
    keys = [f.design for f in st.significant if f.design not in skip][:5]
    if not keys:
        return None
    m = lin.residual.shape[1]
    pool = {k: X for k, _, X in _designs(lin, features, m, 4, 5)}
    if directions:
        pool.update((k, X) for k, _, X in direction_designs(lin, directions, features))
    cols = [pool[k] for k in keys if k in pool]
    return np.concatenate(cols, axis=1) if cols else None


def _union_variance(lin: Linearisation, st: StructureTest, U: np.ndarray | None) -> float:
    """Residual variance once the union of the significant structure designs joins the model."""
    if U is None:
        return st.rss / max(st.dof, 1)
    M = lin.residual.size
    Q = _basis(lin.jacobian.reshape(M, -1))
    w_perp = _perp(Q, lin.residual.reshape(-1))
    Xp = _basis(_perp(Q, U), rtol=1e-8)
    dof = st.dof - Xp.shape[1]
    if dof < 20:
        return st.rss / max(st.dof, 1)
    return max(st.rss - float(np.sum((Xp.T @ w_perp) ** 2)), 0.0) / dof


def rss_without(
    lin: Linearisation, label: str, n_linear: int, values: np.ndarray, extra: np.ndarray | None = None
) -> tuple[float, float, int]:
    """``(RSS without the term, RSS with it, its column count)``: its prediction taken out, the rest refitted
    (linearised, as :func:`.selection.gain_given_others`); ``extra`` columns fitted in both."""
    M = lin.residual.size
    A = lin.jacobian.reshape(M, -1)
    cols = [i for i, n in enumerate(lin.names) if n.startswith(label + ".")]
    rest = [i for i in range(A.shape[1]) if i not in cols]
    w = lin.residual.reshape(-1)
    y = w + A[:, cols[:n_linear]] @ np.asarray(values, dtype=float)[:n_linear]
    E = np.zeros((M, 0)) if extra is None else extra
    r_wo = _perp(_basis(np.concatenate([A[:, rest], E], axis=1)), y)
    r_w = _perp(_basis(np.concatenate([A, E], axis=1)), w)
    return float(r_wo @ r_wo), float(r_w @ r_w), len(cols)


def shares(
    lin: Linearisation,
    st: StructureTest,
    terms: list[tuple[str, int, np.ndarray, str | None]],
    features: list[Feature],
    directions,
    min_share: float,
    margin: float = 10.0,
) -> ShareCheck:
    """The share of what is left and the gain given the structure (module docstring) of each
    ``(label, n_linear, values, own design key or None)`` term."""
    U = structure_union(lin, st, features, directions)
    union = _union_variance(lin, st, U)
    if st.pure_error_variance is not None:
        reference, s2 = "replicate measurements", float(st.pure_error_variance)
    elif st.noise_trust is not None:
        reference, s2 = "stated noise", min(1.0, union)
    else:
        reference, s2 = "the structure designs", union
    left = max(st.rss - st.dof * s2, 0.0)
    check = ShareCheck(min_share, reference, s2, left, left / st.rss if st.rss > 0 else 0.0, margin)
    M = lin.residual.size
    for label, n_linear, values, own in terms:
        rss_wo, _, k = rss_without(lin, label, n_linear, values)
        gain = max(rss_wo - st.rss - k * s2, 0.0)
        check.shares[label] = gain / (gain + left) if gain + left > 0 else 1.0
        U_e = structure_union(lin, st, features, directions, (own,)) if own else U
        if U_e is not None:
            wo, w, _ = rss_without(lin, label, n_linear, values, U_e)
            check.gain_given_structure[label] = float(M * np.log(max(wo, 1e-300) / max(w, 1e-300)) - k * np.log(M))
    return check
