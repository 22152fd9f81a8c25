"""Is anything systematic left in the residuals? Tests that do not depend on the stated noise.

The verdict must not flip when only the stated noise changes (the model, hence the residuals, stay
the same): so whether a gap is left is decided by *F-tests*, which compare two residual sums of
the same data and are exact for a linear Gaussian model whatever the noise level. With ``A`` the
model's whitened Jacobian (everything fitted), ``w_perp`` the residual with ``span(A)`` projected
out and ``X`` a design of possible systematic residual (projected out the same way, rank ``k``)::

    F = ((RSS_0 - RSS_X) / k) / (RSS_X / (M - rank A - k))  ~  F(k, M - rank A - k)  under "no gap".

The designs (none is a catalog effect: they look for what the catalog does not have):

* **per feature** (each joint angle, torque, approach direction, time, temperature, speed, range,
  workspace coordinate ...): one indicator column per bin and measured component (the bins of
  :mod:`.localise`): the residual's mean changes along the feature;
* **smooth field**: every measured component as a quadratic polynomial of the *spatial* features
  (where the tool is in the workspace, :attr:`Feature.spatial`): a distortion of the measuring
  instrument or a deformation of the cell over the workspace.

* **the end test's designs** (:mod:`.end_test`, when the problem gives them): each joint's error
  direction times smooth functions of every feature (an error driven by another joint's angle), the
  lack-of-fit test against replicate measurements, and the residuals against the instrument's stated
  noise (trusted to a factor ``noise_trust``).

Bonferroni over the designs at the family-wise level ``alpha`` (the workflow's ``chi2_alpha``).
A stated noise that is wrong changes none of these numbers; it changes the chi-square test of the
residuals against it, which the workflow reports as the *noise check* (:mod:`.workflow`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations_with_replacement

import numpy as np
from scipy import stats

from plugins.model_gap.core.end_test import direction_designs, replicate_finding, stated_noise_finding
from plugins.model_gap.core.interfaces import F64, Feature, Linearisation
from plugins.model_gap.core.localise import _bins
from plugins.model_gap.core.selection import _basis, _perp


@dataclass
class StructureFinding:
    """One design's F-test: ``design`` (``feature:<name>`` or ``field``), its label, F, dof, p-values."""

    design: str
    label: str
    k: int
    dof: int
    f_stat: float
    p_value: float
    p_corrected: float


@dataclass
class StructureTest:
    """The residual-structure tests of one model (see the module docstring)."""

    alpha: float
    n_tests: int
    findings: list[StructureFinding] = field(default_factory=list)  # every design, strongest first
    rss: float = 0.0  # whitened residual sum of squares with the model's span projected out
    dof: int = 0  # M - rank A
    pure_error_variance: float | None = None  # whitened, from replicate measurements (None: no replicates)
    noise_trust: float | None = None  # the stated noise was tested, trusted to this factor (None: estimated)

    @property
    def found(self) -> bool:
        """Some design explains part of the residuals at the family-wise level ``alpha``."""
        return bool(self.findings) and self.findings[0].p_corrected < self.alpha

    @property
    def significant(self) -> list[StructureFinding]:
        return [f for f in self.findings if f.p_corrected < self.alpha]

    def describe(self, top: int = 3) -> str:
        """``the mean residual changes along joint 2 angle: F = 9.1, corrected p = 2e-07, and ...``."""
        sig = self.significant[:top]
        return ", and ".join(f"{f.label}: F = {f.f_stat:.2f}, corrected p = {f.p_corrected:.2g}" for f in sig)


def _field_design(spatial: list[Feature], m: int) -> F64 | None:
    """``(N m, m * terms)``: each component as a quadratic polynomial of the standardised spatial features."""
    if not spatial:
        return None
    X = np.column_stack([f.values for f in spatial])
    sd = X.std(axis=0)
    X = (X - X.mean(axis=0)) / np.where(sd > 0, sd, 1.0)
    terms = [np.ones(len(X))] + [X[:, i] for i in range(X.shape[1])]
    terms += [X[:, i] * X[:, j] for i, j in combinations_with_replacement(range(X.shape[1]), 2)]
    T = np.column_stack(terms)
    out = np.zeros((len(X) * m, T.shape[1] * m))
    for c in range(m):
        out[c::m, c * T.shape[1] : (c + 1) * T.shape[1]] = T
    return out


def _bin_design(f: Feature, m: int, n_bins: int, min_bin: int) -> F64 | None:
    groups = [mask for _, mask in _bins(f, n_bins) if mask.sum() >= min_bin]
    if len(groups) < 2:
        return None
    out = np.zeros((f.values.size * m, len(groups) * m))
    for b, mask in enumerate(groups):
        for c in range(m):
            out[np.flatnonzero(mask) * m + c, b * m + c] = 1.0
    return out


def residual_structure(
    lin: Linearisation,
    features: list[Feature],
    alpha: float,
    *,
    n_bins: int = 4,
    min_bin: int = 5,
    directions: list[tuple[str, str, F64]] | None = None,
    replicates: list[np.ndarray] | None = None,
    noise_trust: float | None = None,
) -> StructureTest:
    """F-test every design of the module docstring against the residuals of ``lin``'s model.

    ``directions``: the problem's error directions (:mod:`.end_test`); ``replicates``: groups of rows
    measured at the same pose; ``noise_trust``: test the residuals against the stated noise (given, not
    estimated) trusted to this factor."""
    N, m = lin.residual.shape
    M = N * m
    w = lin.residual.reshape(-1)
    Q = _basis(lin.jacobian.reshape(M, -1))
    w_perp = _perp(Q, w)
    rss0 = float(w_perp @ w_perp)
    designs = _designs(lin, features, m, n_bins, min_bin)
    if directions:
        designs += direction_designs(lin, directions, features)
    findings = []
    for key, label, X in designs:
        Xp = _basis(_perp(Q, X), rtol=1e-8)
        k = Xp.shape[1]
        dof = M - Q.shape[1] - k
        if k == 0 or dof <= 0 or rss0 <= 0:
            continue
        rss = max(rss0 - float(np.sum((Xp.T @ w_perp) ** 2)), 1e-300)
        F = ((rss0 - rss) / k) / (rss / dof)
        findings.append(StructureFinding(key, label, k, dof, float(F), float(stats.f.sf(F, k, dof)), 1.0))
    dof0 = M - Q.shape[1]
    pure = None
    rep = replicate_finding(w_perp, m, replicates, dof0) if replicates else None
    if rep is not None:
        F, df_pe, pure = rep
        lab = f"the residuals exceed the replicate measurements' scatter ({np.sqrt(F):.2f}x its sigma)"
        findings.append(
            StructureFinding("replicates", lab, dof0 - df_pe, df_pe, F, float(stats.f.sf(F, dof0 - df_pe, df_pe)), 1.0)
        )
    if noise_trust is not None and rss0 > 0:
        ratio2, p = stated_noise_finding(rss0, dof0, noise_trust)
        lab = f"the residuals exceed {noise_trust:g}x the stated noise ({np.sqrt(rss0 / max(dof0, 1)):.2f}x it)"
        findings.append(StructureFinding("stated_noise", lab, dof0, dof0, ratio2, p, 1.0))
    n = len(findings)
    for f in findings:
        f.p_corrected = min(1.0, f.p_value * n)
    findings.sort(key=lambda f: (f.p_value, -f.f_stat))
    return StructureTest(alpha, n, findings, rss0, dof0, pure, noise_trust)


def _designs(
    lin: Linearisation, features: list[Feature], m: int, n_bins: int, min_bin: int
) -> list[tuple[str, str, F64]]:
    """The per-feature bin designs and the smooth field over the spatial features."""
    N = lin.residual.shape[0]
    designs: list[tuple[str, str, F64]] = []
    for f in features:
        if f.values.shape != (N,) or not np.all(np.isfinite(f.values)):
            continue
        X = _bin_design(f, m, n_bins, min_bin)
        if X is not None:
            designs.append((f"feature:{f.name}", f"the mean residual changes along {f.label}", X))
    X = _field_design([f for f in features if f.spatial and f.values.shape == (N,)], m)
    if X is not None:
        designs.append(("field", "a smooth field over the workspace (quadratic in x, y, z)", X))
    return designs
