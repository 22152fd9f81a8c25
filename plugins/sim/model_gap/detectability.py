"""A-priori detectability and identifiability of a simulated case's hidden effects, from the truth alone.

Used by the benchmark to say *which* cases a method can be expected to get right before looking at
what it said. Everything here is computed from the simulated truth (:class:`~.simulate.SimulatedCampaign`:
the noise-free displacement each hidden effect makes, the true frames, the campaign's inputs) and
the noise level; never from the noisy measurements or the workflow's result.

Notation (whitened by the per-axis noise sigma, ``M = 3 N`` numbers): ``C`` the columns of the
baseline calibration the workflow fits first (frame + tool point in the ``tracker`` scenario, none
with known frames), ``s_i`` the displacement of hidden effect ``i`` alone, ``s`` all together,
``D_c`` the design (Jacobian columns at the truth) of catalog candidate ``c`` -- the same families
the workflow tests, one design per grid point of a time constant -- and ``P_perp[X]`` the projector
onto the complement of ``span(X)``. The true effect ``i``'s design ``D_i`` is its candidate's design
at the grid point that fits ``s_i`` best.

* **Detectability** of the case: ``lambda_det = |P_D P_perp[C] s|^2``, the noncentrality of the
  workflow's F-test (family-wise ``alpha`` Bonferroni-corrected over the round's tests) aimed at the
  true effects' design ``D = P_perp[C] [D_1 .. D_n]`` (``k`` = its rank); power = ``P(F'(k, M - rank C - k,
  lambda_det) > F_crit)``. Also reported: ``lambda_gap = |P_perp[C] s|^2`` and the power of the
  workflow's chi-square test of the residuals (``chi2_alpha``), the test that tells ``no_gap``.
* **Identifiability** of effect ``i`` against the best alternative catalog explanation: with
  ``O`` the other hidden effects' designs and signals (the model that already has them),
  ``lambda_id = min_r |P_Z P_perp[C, O, D_r] s_i|^2`` over every catalog candidate ``r`` that is not
  hidden (every grid point) and ``r = none``, ``Z = P_perp[C, O, D_r] D_i``: the smallest signal of
  effect ``i`` no rival can take -- the noncentrality of the F-test of ``D_i`` added on top of the
  rival; power at the same corrected ``alpha``.

Classes (thresholds from the workflow's own test levels and a standard power target, ``power = 0.8``
[Cohen 1988], not fitted to outcomes):

* ``identifiable``: detection power >= 0.8 and every hidden effect's identifiability power >= 0.8;
* ``confounded`` (detectable but confounded): detection power >= 0.8, some effect below;
  its ``identifiable_part`` lists the effects above (the right answer names only those, or nothing);
* ``undetectable``: detection power < 0.8 (the right answer is ``no_gap`` or nothing named);
* ``noise``: no hidden effect.

The rivals are every catalog candidate, ``robot_scale`` (a uniform scale of all robot lengths and the
tool point) included. After a frame calibration a range scale about the sensor is exactly that
(``(1+e)(R x + t) = R((1+e) x) + (1+e) t``, and the position of an all-revolute chain is homogeneous
of degree 1 in its lengths), so in the ``tracker`` scenario ``depth_scale`` and ``robot_scale`` each
have ``lambda_id = 0`` with the other as the rival: such a case is ``confounded`` by construction.
:func:`uniform_scale_column` computes that column independently of the catalog (for the tests).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from plugins.model_gap.core.interfaces import Candidate
from plugins.model_gap.core.selection import SelectionConfig, _basis, _perp
from plugins.model_gap.core.workflow import GapConfig, collect_candidates
from plugins.model_gap.effects import builtin_families
from plugins.model_gap.problem import KinematicGapProblem, ProblemConfig
from plugins.sim.model_gap.simulate import HiddenCase, SimulatedCampaign

POWER_TARGET = 0.8  # the conventional power target (Cohen 1988); not fitted to the suite
CLASSES = ("identifiable", "confounded", "undetectable")


@dataclass
class EffectIdentifiability:
    label: str  # name@where
    k: int  # rank of the effect's design after the calibration
    lambda_alone: float  # |P_D P_perp[C] s_i|^2: the effect alone after the calibration
    lambda_given_others: float  # ... and after the other hidden effects
    lambda_id: float  # ... and after the best rival: the smallest independent signal
    rival: str  # the candidate that leaves the smallest independent signal ("none": no rival takes any)
    power: float  # of the workflow's F-test at lambda_id
    identifiable: bool
    # variant: power of the decisive-margin rule instead (BIC gain over the rival >= bic_margin, i.e.
    # a chi-square gain >= bic_margin + (k + shape parameters) ln M): a check that the class does not hinge
    # on which of the workflow's two levels is used
    power_margin: float


@dataclass
class CaseClassification:
    cls: str  # identifiable | confounded | undetectable | noise
    lambda_gap: float  # |P_perp[C] s|^2
    lambda_det: float  # |P_D P_perp[C] s|^2
    k_det: int
    power_det: float  # F-test aimed at the true design, corrected alpha
    power_chi2: float  # the workflow's chi-square test of the residuals (no_gap vs gap)
    n_tests: int  # Bonferroni count of the workflow's first round (candidates x grid points)
    alpha_test: float  # alpha / n_tests
    effects: list[EffectIdentifiability] = field(default_factory=list)
    identifiable_part: list[str] = field(default_factory=list)
    # the class with the decisive-margin variant of the identifiability power (see EffectIdentifiability)
    cls_margin: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _power_f(lam: float, k: int, dof: int, alpha: float) -> float:
    if k <= 0 or dof <= 0:
        return 0.0
    crit = stats.f.isf(alpha, k, dof)
    return float(stats.ncf.sf(crit, k, dof, max(lam, 1e-12)))


def _new_directions(Q: np.ndarray, X: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis of the part of ``span(X)`` outside ``span(Q)`` (``Q`` orthonormal).

    Columns are scaled to unit norm first; directions whose singular value is below ``tol`` (the
    workflow's ``absorbed_tol``: the share of a unit column the calibration cannot produce) count as absorbed.
    """
    if X.shape[1] == 0:
        return np.zeros((X.shape[0], 0))
    norms = np.linalg.norm(X, axis=0)
    Xp = _perp(Q, X[:, norms > 0] / norms[norms > 0])
    if Xp.shape[1] == 0:
        return Xp
    U, sv, _ = np.linalg.svd(Xp, full_matrices=False)
    return U[:, sv > tol]


def _proj_norm2(Q: np.ndarray, y: np.ndarray) -> float:
    """``|P_Q y|^2`` for an orthonormal ``Q``."""
    return float(np.sum((Q.T @ y) ** 2)) if Q.shape[1] else 0.0


def uniform_scale_column(camp: SimulatedCampaign) -> np.ndarray:
    """``(3N,)`` displacement (m) of the measured point per unit uniform scale of every robot length and
    the tool point (``sum_l L_l dp/dL_l``), at the truth, in the measurement frame."""
    m = camp.truth_model
    assert m is not None and camp.truth_data is not None
    _, J = m.param_jacobian(camp.truth_data.samples.q)
    names, values = m.param_names, m.param_values
    lengths = [i for i, n in enumerate(names) if n.startswith("joint") and n.rsplit(".", 1)[-1] in ("a", "d")]
    tool = [names.index(f"tool.{c}") for c in ("tx", "ty", "tz")]
    # the tool point in the flange frame (the tool parameters included): the tool.t* columns move the
    # measured point along the flange axes
    tool_point = m.T_flange_tcp[:3, 3]
    return (J[:, :3, lengths] @ values[lengths] + J[:, :3, tool] @ tool_point).reshape(-1)


def classify(
    case: HiddenCase,
    camp: SimulatedCampaign,
    *,
    families: list | None = None,
    config: GapConfig | None = None,
    power: float = POWER_TARGET,
) -> CaseClassification:
    """The a-priori class of a case (module docstring); ``config``: the workflow's test levels."""
    if camp.truth_data is None or camp.signal_m is None or camp.calibration_m is None:
        raise ValueError("the campaign carries no truth (made by simulate_campaign?)")
    cfg = config or GapConfig()
    sel: SelectionConfig = cfg.selection
    sigma = case.noise_m
    problem = KinematicGapProblem(camp.truth_model, camp.truth_data, ProblemConfig((), noise_m=sigma))
    cands = [c for c in collect_candidates(problem, families or builtin_families()) if not c.unavailable]
    N = camp.truth_data.n_samples
    M = 3 * N
    QC = _basis(camp.calibration_m / sigma)
    rank_c = QC.shape[1]

    tol = sel.absorbed_tol
    designs, n_tests = _catalog_designs(cands, problem, QC, M, tol)
    alpha_t = sel.alpha / max(n_tests, 1)

    s_tot = camp.signal_m.reshape(-1) / sigma
    y_tot = _perp(QC, s_tot)
    lambda_gap = float(y_tot @ y_tot)
    power_chi2 = _power_chi2(lambda_gap, M - rank_c, cfg.chi2_alpha)
    if not case.effects:
        return CaseClassification("noise", lambda_gap, 0.0, 0, 0.0, power_chi2, n_tests, alpha_t)

    labels = [f"{e.name}@{e.where}" for e in case.effects]
    sig = [x.reshape(-1) / sigma for x in camp.signals_m]
    true_d = _true_designs(labels, sig, designs, QC, tol)
    D_all = _new_directions(QC, np.concatenate(true_d, axis=1), tol)
    k_det = D_all.shape[1]
    lambda_det = _proj_norm2(D_all, y_tot)
    power_det = _power_f(lambda_det, k_det, M - rank_c - k_det, alpha_t)

    effects = [
        _identifiability(i, labels, sig, true_d, designs, QC, M, tol, alpha_t, sel.bic_margin, power)
        for i in range(len(labels))
    ]
    cls = _case_class(power_det, power, [e.identifiable for e in effects])
    part = [e.label for e in effects if e.identifiable] if cls != "undetectable" else []
    return CaseClassification(
        cls,
        lambda_gap,
        lambda_det,
        k_det,
        power_det,
        power_chi2,
        n_tests,
        alpha_t,
        effects,
        part,
        _case_class(power_det, power, [e.power_margin >= power for e in effects]),
    )


def _catalog_designs(
    cands: list[Candidate], problem: KinematicGapProblem, QC: np.ndarray, M: int, tol: float
) -> tuple[dict[str, list[np.ndarray]], int]:
    """Every candidate's designs (``(M, k)``, one per grid point), by ``name@where``, and the Bonferroni
    count of the workflow's first round (the designs of every candidate the calibration does not absorb)."""
    designs: dict[str, list[np.ndarray]] = {}
    n_tests = 0
    for c in cands:
        mats = [d.columns.reshape(M, -1) for d in c.designs(problem)]
        designs[f"{c.name}@{c.where}"] = mats
        if any(_new_directions(QC, B, tol).shape[1] for B in mats):
            n_tests += len(mats)
    return designs, n_tests


def _power_chi2(lambda_gap: float, dof: int, chi2_alpha: float) -> float:
    """Power of the workflow's chi-square test of the residuals (``dof`` = M - rank C, at least 1)."""
    dof0 = max(1, dof)
    crit = stats.chi2.isf(chi2_alpha, dof0)
    return float(stats.ncx2.sf(crit, dof0, max(lambda_gap, 1e-12)))


def _true_designs(
    labels: list[str], sig: list[np.ndarray], designs: dict[str, list[np.ndarray]], QC: np.ndarray, tol: float
) -> list[np.ndarray]:
    """Each hidden effect's design at its best-fitting grid point (the largest signal after the calibration)."""
    true_d = []
    for lab, s in zip(labels, sig, strict=True):
        mats = designs.get(lab)
        if not mats:
            raise ValueError(f"{lab} is not a candidate of the catalog for this campaign")
        ys = _perp(QC, s)
        true_d.append(max(mats, key=lambda B: _proj_norm2(_new_directions(QC, B, tol), ys)))
    return true_d


def _independent(Qb: np.ndarray, extra: np.ndarray, s: np.ndarray, D: np.ndarray, tol: float) -> tuple[float, int, int]:
    """(noncentrality of D's F-test on top of Qb + extra, rank of that model, rank of D's new part)."""
    Q = np.concatenate([Qb, _new_directions(Qb, extra, tol)], axis=1)
    Z = _new_directions(Q, D, tol)
    return _proj_norm2(Z, _perp(Q, s)), Q.shape[1], Z.shape[1]


def _identifiability(
    i: int,
    labels: list[str],
    sig: list[np.ndarray],
    true_d: list[np.ndarray],
    designs: dict[str, list[np.ndarray]],
    QC: np.ndarray,
    M: int,
    tol: float,
    alpha_t: float,
    bic_margin: float,
    power: float,
) -> EffectIdentifiability:
    """Identifiability of hidden effect ``i`` (module docstring): its signal left on top of the calibration,
    the other hidden effects and the best rival (the candidate, not hidden, that leaves the least)."""
    lab, s, D = labels[i], sig[i], true_d[i]
    others = [X for j in range(len(labels)) if j != i for X in (true_d[j], sig[j][:, None])]
    Qb = np.concatenate([QC, _new_directions(QC, np.concatenate(others, axis=1), tol)], axis=1) if others else QC
    lam_alone = _proj_norm2(_new_directions(QC, D, tol), _perp(QC, s))
    lam_given, rank_b, k_i = _independent(Qb, np.zeros((M, 0)), s, D, tol)
    best = (lam_given, "none", rank_b, k_i)
    for r, mats in designs.items():
        if r in labels:
            continue
        for B in mats:
            lam, rk, k = _independent(Qb, B, s, D, tol)
            if lam < best[0]:
                best = (lam, r, rk, k)
    lam_id, rival, rank_r, k_r = best
    p_id = _power_f(lam_id, k_r, M - rank_r - k_r, alpha_t)
    k_shape = 1 if len(designs[lab]) > 1 else 0  # a profiled time constant
    gain_needed = bic_margin + (k_r + k_shape) * np.log(M)
    p_margin = float(stats.ncx2.sf(gain_needed, k_r, max(lam_id, 1e-12))) if k_r else 0.0
    return EffectIdentifiability(lab, k_i, lam_alone, lam_given, lam_id, rival, p_id, p_id >= power, p_margin)


def _case_class(power_det: float, power: float, ok: list[bool]) -> str:
    """``undetectable`` below the detection power, else ``identifiable`` if every effect is, else ``confounded``."""
    if power_det < power:
        return "undetectable"
    return "identifiable" if all(ok) else "confounded"
