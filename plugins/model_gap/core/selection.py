"""Scoring candidate effects against the current model, and the rule that names one (or none).

Everything is computed on whitened residuals ``w`` (``M = N m`` numbers; unit variance if the
noise specification is right) with the current model linearised: ``w ~ A a + B b + noise`` where
``A`` holds the parameters already fitted (baseline calibration + accepted effects) and ``B`` a
candidate's. Fitting ``[A B]`` jointly is what "after calibration" means: a candidate is only
credited with the part of its signature that the calibration parameters cannot produce
(Frisch-Waugh-Lovell: its coefficient is the regression of ``w`` on ``B`` with ``A``'s span
projected out). For each candidate:

* **independent fraction** ``|B_perp| / |B|`` per column: 0 means the calibration explains the effect
  completely (*absorbed*, reported, never named), small means confounded (reported with the
  calibration parameters it resembles);
* **F-test** of ``H0: b = 0``: ``F = (dRSS / k) / (RSS_c / (M - p - k))``, exact for a linear
  Gaussian model with unknown variance (robust to an optimistic noise spec); the p-value is
  Bonferroni-corrected over every test of the iteration (candidates x grid points of shape
  parameters: the profile over a time constant is a maximum over the grid);
* **BIC** with the variance estimated, ``BIC = M ln(RSS / M) + k ln M``; ``dBIC`` relative to the
  current model (``2 ln`` of the Bayes factor, approximately);
* **k-fold cross-validation** by samples (the same seeded folds for all candidates; shape parameters
  chosen inside each training fold): held-out RMS in physical units, and a paired one-sided z-test of
  the per-sample held-out squared errors against the current model's.

The decision rule (:func:`decide`; ``docs/model_gap.md`` explains why) considers the candidates that
(1) pass the corrected F-test at the family-wise level ``alpha``, (2) have ``dBIC > 0``, (3) improve
the held-out error (``z >= cv_z``) and (4) have physically valid fitted values, in order of
decreasing ``dBIC``, and names the first that is *decisive* over every other candidate ``r``: either
``dBIC_r <= dBIC_w - margin`` (as single explanations the data prefer the winner by a Bayes factor of
~150), or the winner still gains ``>= margin`` in BIC when added on top of ``r`` (the close
*contenders*; else the two explain the same part of the gap). When no eligible candidate is decisive
the round is ambiguous: nothing is named, and the candidates that explain the same part of the gap
are reported as *tied* (:attr:`Decision.tied`), with what would separate them when their effects
say (a candidate's optional ``tie_advice``: rival effect name -> advice; else "collect data that
separates them"). An exact tie -- two effects whose columns span the same direction after the
calibration, e.g. a range scale and a uniform robot scale once the frame is fitted -- always ends
here: each gains ``-k ln M`` on top of the other. The loop then adds the tied group as *one* term
(they predict the same data to within the margin), evaluated as its :attr:`Decision.representative`
(:func:`representative`: the eligible member with the largest dBIC; members within ``1e-6`` of it
-- an exact tie -- are ordered by parameter count, then label, so the choice does not depend on
rounding) and named after the whole group, never after the representative alone.

:func:`gain_given_others` is the backward check of the loop: the BIC an added effect still gains
given every other effect of the current model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import stats

from plugins.model_gap.core.interfaces import F64, Candidate, Design, GapProblem, Linearisation


@dataclass
class SelectionConfig:
    """Parameters of the decision rule (defaults derived in docs/model_gap.md)."""

    alpha: float = 1e-3  # family-wise false-positive probability per iteration
    bic_margin: float = 10.0  # "very strong" evidence (Kass & Raftery 1995): Bayes factor ~150
    cv_folds: int = 5
    cv_z: float = 1.645  # held-out improvement, one-sided 5 %
    absorbed_tol: float = 1e-4  # independent fraction below this: the calibration explains the effect
    seed: int = 0


@dataclass
class CandidateScore:
    """How well one candidate explains the current residuals (whitened units unless named)."""

    candidate: Candidate
    name: str
    where: str
    k: int = 0  # linear parameters identifiable after calibration (rank)
    k_shape: int = 0
    n_designs: int = 1  # grid points of the shape parameters (multiple-testing count)
    independent_fraction: float = 0.0  # smallest over the candidate's columns
    confounded_with: list[tuple[str, float]] = field(default_factory=list)
    unavailable: str | None = None
    absorbed: bool = False
    rss: float = np.nan
    delta_rss: float = 0.0
    delta_bic: float = -np.inf
    f_stat: float = 0.0
    p_value: float = 1.0
    p_adjusted: float = 1.0
    cv_rms: float = np.nan  # held-out RMS, SI units (3-D norm over the components)
    cv_gain: float = 0.0  # current model's held-out RMS minus this one's (SI)
    cv_z: float = 0.0
    beta: F64 = field(default_factory=lambda: np.zeros(0))  # linear parameters (joint fit)
    shape: dict[str, float] = field(default_factory=dict)
    design: Design | None = None
    eligible: bool = False
    reasons: list[str] = field(default_factory=list)

    @property
    def testable(self) -> bool:
        return self.unavailable is None and not self.absorbed

    @property
    def label(self) -> str:
        return f"{self.name}@{self.where}"

    @property
    def values(self) -> F64:
        """Linear then shape parameter values, the order of ``candidate.param_names``."""
        return np.concatenate([self.beta, [self.shape[s] for s in self.candidate.shape_names]])


@dataclass
class BaselineScore:
    rss: float
    dof: int
    rank: int
    cv_rms: float
    cv_sq: F64  # per-sample held-out squared error (whitened)
    in_sample_rms: float


@dataclass
class Decision:
    status: Literal["named", "none", "ambiguous"]
    winner: CandidateScore | None  # ambiguous: the leader (largest dBIC), which is NOT named
    reason: str
    contenders: list[tuple[str, float]] = field(default_factory=list)  # (label, dBIC of winner given it)
    # ambiguous: the leader and every candidate that explains the same part of the gap (none is named),
    # their dBIC as single explanations, and what would separate them
    tied: list[str] = field(default_factory=list)
    tied_delta_bic: dict[str, float] = field(default_factory=dict)
    advice: list[str] = field(default_factory=list)
    # ambiguous: the member the tie term is evaluated as when the loop adds the group (see representative)
    representative: CandidateScore | None = None


# --------------------------------------------------------------------------- linear algebra


def _basis(A: F64, rtol: float = 1e-10) -> F64:
    """Orthonormal basis of the column space of ``A`` (SVD, rank by relative singular value)."""
    if A.shape[1] == 0:
        return np.zeros((A.shape[0], 0))
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    r = int(np.sum(s > rtol * max(s[0], 1e-300)))
    return U[:, :r]


def _perp(Q: F64, X: F64) -> F64:
    return X - Q @ (Q.T @ X) if Q.shape[1] else X.copy()


class _Fold:
    """One cross-validation split with the current model's fit precomputed."""

    def __init__(self, A: F64, w: F64, rows_train: np.ndarray, rows_test: np.ndarray, n_comp: int) -> None:
        self.tr, self.te = rows_train, rows_test
        self.n_comp = n_comp
        self.A_tr, self.A_te = A[rows_train], A[rows_test]
        self.w_tr, self.w_te = w[rows_train], w[rows_test]
        self.Q = _basis(self.A_tr)
        self.pinv = np.linalg.pinv(self.A_tr, rcond=1e-10) if A.shape[1] else np.zeros((0, len(rows_train)))
        self.w_perp = _perp(self.Q, self.w_tr)
        self.base_err = self.w_te - self.A_te @ (self.pinv @ self.w_tr)

    def held_out(self, B: F64) -> tuple[F64, float]:
        """(held-out residual of the model + B, training RSS) for a candidate design B (M, k)."""
        Bt = B[self.tr]
        Bp = _perp(self.Q, Bt)
        beta, *_ = np.linalg.lstsq(Bp, self.w_perp, rcond=1e-10)
        rss_tr = float(np.sum((self.w_perp - Bp @ beta) ** 2))
        alpha = self.pinv @ (self.w_tr - Bt @ beta)
        return self.w_te - self.A_te @ alpha - B[self.te] @ beta, rss_tr


def make_folds(n_samples: int, n_folds: int, seed: int) -> list[np.ndarray]:
    """Seeded assignment of samples to folds (balanced sizes)."""
    perm = np.random.default_rng(seed).permutation(n_samples)
    return [np.sort(perm[f::n_folds]) for f in range(n_folds)]


class Scorer:
    """Scores candidates against one linearisation (see the module docstring)."""

    def __init__(self, lin: Linearisation, cfg: SelectionConfig) -> None:
        self.lin, self.cfg = lin, cfg
        N, m = lin.residual.shape
        self.N, self.m = N, m
        self.M = N * m
        self.w = lin.residual.reshape(-1)
        self.A = lin.jacobian.reshape(self.M, -1)
        self.Q = _basis(self.A)
        self.rank = self.Q.shape[1]
        self.w_perp = _perp(self.Q, self.w)
        self.rss0 = float(self.w_perp @ self.w_perp)
        self.sigma2 = np.repeat(lin.sigma**2, m)
        folds = make_folds(N, cfg.cv_folds, cfg.seed)
        self.folds: list[_Fold] = []
        for f in folds:
            test = np.zeros(N, bool)
            test[f] = True
            rows_te = np.flatnonzero(np.repeat(test, m))
            rows_tr = np.flatnonzero(np.repeat(~test, m))
            self.folds.append(_Fold(self.A, self.w, rows_tr, rows_te, m))
        cv_sq = np.zeros(N)
        for fold in self.folds:
            cv_sq[fold.te[:: self.m] // self.m] = self._per_sample(fold.base_err)
        self.base_cv_sq = cv_sq
        self.baseline = BaselineScore(
            rss=self.rss0,
            dof=self.M - self.rank,
            rank=self.rank,
            cv_rms=self._rms_physical(self._cv_errors(None)),
            cv_sq=cv_sq,
            in_sample_rms=float(np.sqrt(np.sum(self.w_perp**2 * self.sigma2) / N)),
        )
        # normalised calibration columns, for "acts like" reports
        norms = np.linalg.norm(self.A, axis=0)
        self.A_unit = self.A / np.where(norms > 0, norms, 1.0)

    # -- helpers ----------------------------------------------------------------------------------

    def _per_sample(self, e: F64) -> F64:
        return np.sum(e.reshape(-1, self.m) ** 2, axis=1)

    def _cv_errors(self, designs: list[Design] | None) -> F64:
        """Held-out residual of every row (whitened), shape parameters chosen per training fold."""
        out = np.zeros(self.M)
        for fold in self.folds:
            if designs is None:
                out[fold.te] = fold.base_err
                continue
            best, best_rss = None, np.inf
            for d in designs:
                e, rss = fold.held_out(d.columns.reshape(self.M, -1))
                if rss < best_rss:
                    best, best_rss = e, rss
            out[fold.te] = best
        return out

    def _rms_physical(self, e: F64) -> float:
        return float(np.sqrt(np.sum(e**2 * self.sigma2) / self.N))

    # -- scoring ----------------------------------------------------------------------------------

    def score(self, cand: Candidate, problem: GapProblem) -> CandidateScore:
        sc = CandidateScore(cand, cand.name, cand.where, k_shape=len(cand.shape_names), unavailable=cand.unavailable)
        if cand.unavailable:
            sc.reasons.append(cand.unavailable)
            return sc
        designs = cand.designs(problem)
        if not designs:
            sc.unavailable = "no design for these data"
            return sc
        sc.n_designs = len(designs)
        best = None
        for d in designs:
            B = d.columns.reshape(self.M, -1)
            norms = np.linalg.norm(B, axis=0)
            if not np.all(norms > 0):
                continue
            Bp = _perp(self.Q, B)
            frac = np.linalg.norm(Bp, axis=0) / norms
            s = np.linalg.svd(Bp / norms, compute_uv=False)
            k_eff = int(np.sum(s > self.cfg.absorbed_tol))
            beta, *_ = np.linalg.lstsq(Bp, self.w_perp, rcond=self.cfg.absorbed_tol)
            rss = float(np.sum((self.w_perp - Bp @ beta) ** 2))
            if best is None or rss < best[0]:
                best = (rss, d, frac, k_eff, beta, B)
        if best is None:
            sc.unavailable = "the effect leaves no trace on these samples (zero regressor)"
            sc.reasons.append(sc.unavailable)
            return sc
        rss, d, frac, k_eff, beta, B = best
        sc.independent_fraction = float(frac.min())
        sc.design, sc.shape, sc.beta = d, dict(d.shape), beta
        coef, *_ = np.linalg.lstsq(self.A_unit, B / np.linalg.norm(B, axis=0), rcond=1e-10)
        top = np.argsort(-np.abs(coef).max(axis=1))[:3] if coef.size else []
        sc.confounded_with = [(self.lin.names[i], float(np.abs(coef[i]).max())) for i in top if coef.size]
        if k_eff == 0:
            sc.absorbed = True
            sc.reasons.append("absorbed: the calibration parameters produce the same signature")
            return sc
        sc.k = k_eff
        sc.rss = rss
        sc.delta_rss = self.rss0 - rss
        dof = self.M - self.rank - k_eff
        sc.f_stat = (sc.delta_rss / k_eff) / (rss / dof) if rss > 0 and dof > 0 else np.inf
        sc.p_value = float(stats.f.sf(sc.f_stat, k_eff, dof)) if dof > 0 else 1.0
        sc.delta_bic = self.M * np.log(self.rss0 / rss) - (k_eff + sc.k_shape) * np.log(self.M)
        e_cv = self._cv_errors(designs)
        sc.cv_rms = self._rms_physical(e_cv)
        sc.cv_gain = self.baseline.cv_rms - sc.cv_rms
        d_i = self.base_cv_sq - self._per_sample(e_cv)
        sd = float(np.std(d_i, ddof=1))
        sc.cv_z = float(np.mean(d_i) / (sd / np.sqrt(self.N))) if sd > 0 else 0.0
        return sc

    def identifiable_part(self, design: Design, beta: F64) -> F64:
        """``(N, m)`` whitened contribution ``B beta`` with the current model's span projected out.

        What the residuals of the current (calibrated) model can show of the effect: the projected-out
        part is what the calibration parameters absorb when the effect is fitted jointly with them.
        """
        c = design.columns.reshape(self.M, -1) @ beta
        return _perp(self.Q, c).reshape(self.N, self.m)

    def rss_together(self, designs: list[Design]) -> float:
        """RSS of the current model plus several candidate designs at once."""
        B = np.concatenate([d.columns.reshape(self.M, -1) for d in designs], axis=1)
        Bp = _perp(self.Q, B)
        beta, *_ = np.linalg.lstsq(Bp, self.w_perp, rcond=self.cfg.absorbed_tol)
        return float(np.sum((self.w_perp - Bp @ beta) ** 2))


def score_all(
    lin: Linearisation, candidates: list[Candidate], problem: GapProblem, cfg: SelectionConfig
) -> tuple[Scorer, BaselineScore, list[CandidateScore]]:
    """Score every candidate; mark the eligible ones (Bonferroni over all tests of this iteration)."""
    scorer = Scorer(lin, cfg)
    scores = [scorer.score(c, problem) for c in candidates]
    n_tests = sum(s.n_designs for s in scores if s.testable)
    for s in scores:
        if not s.testable:
            continue
        s.p_adjusted = min(1.0, s.p_value * n_tests)
        lo, hi = np.asarray(s.candidate.lower, float), np.asarray(s.candidate.upper, float)
        in_bounds = bool(np.all(s.beta >= lo) and np.all(s.beta <= hi)) if s.beta.size == lo.size else True
        checks = [
            (s.p_adjusted < cfg.alpha, f"not significant (corrected p = {s.p_adjusted:.2g} >= {cfg.alpha:g})"),
            (s.delta_bic > 0, f"BIC does not improve (dBIC = {s.delta_bic:.1f})"),
            (s.cv_z >= cfg.cv_z, f"held-out error does not improve (z = {s.cv_z:.2f} < {cfg.cv_z})"),
            (in_bounds, "fitted value outside the effect's physical range"),
        ]
        s.reasons += [msg for ok, msg in checks if not ok]
        s.eligible = all(ok for ok, _ in checks)
    return scorer, scorer.baseline, scores


def _contenders(scorer: Scorer, c: CandidateScore, scores: list[CandidateScore], margin: float):
    """``(contenders, ambiguous)`` of candidate ``c``: every other testable candidate within ``margin`` of
    its dBIC or above it, with the BIC ``c`` still gains when added on top of it; those where the gain
    is below ``margin`` explain the same part of the gap as ``c``."""
    contenders: list[tuple[str, float]] = []
    ambiguous: list[str] = []
    for r in scores:
        # a candidate whose dBIC is ``margin`` below c's is no rival: as the explanation of the gap the
        # data prefer c over it by a Bayes factor of ~150 (even when c adds little on top of it: then c
        # is the simpler explanation of the same part, e.g. a constant range scale vs a fast drift)
        if r is c or not r.testable or not np.isfinite(r.delta_bic) or r.delta_bic <= c.delta_bic - margin:
            continue
        assert c.design is not None and r.design is not None
        rss_both = scorer.rss_together([r.design, c.design])
        gain = scorer.M * np.log(r.rss / rss_both) - (c.k + c.k_shape) * np.log(scorer.M)
        contenders.append((r.label, float(gain)))
        if gain < margin:
            ambiguous.append(r.label)
    return contenders, ambiguous


def decide(scorer: Scorer, scores: list[CandidateScore], cfg: SelectionConfig) -> Decision:
    """The naming rule of the module docstring.

    The eligible candidates are tried in order of decreasing dBIC; the first that is decisive over
    every close contender (every candidate within the margin below it, and every one above it) is
    named. A candidate that is not decisive is skipped, not named: an ambiguous pair (two effects that
    explain the same part of the gap) must not stop a different effect, decisively present, from being
    added -- removing its signal is what may let the next round separate the pair. When no eligible
    candidate is decisive the round is ``ambiguous`` (the largest-dBIC one and its rivals are reported).
    """
    eligible = sorted((s for s in scores if s.eligible), key=lambda s: -s.delta_bic)
    if not eligible:
        return Decision("none", None, "no candidate passes the significance, BIC and held-out tests")
    skipped: list[tuple[CandidateScore, list[str], list[tuple[str, float]]]] = []
    for w in eligible:
        contenders, ambiguous = _contenders(scorer, w, scores, cfg.bic_margin)
        if ambiguous:
            skipped.append((w, ambiguous, contenders))
            continue
        reason = f"{w.label}: dBIC {w.delta_bic:.1f}, decisive over every contender"
        if skipped:
            top, amb, _ = skipped[0]
            reason += (
                f" (ranked higher but not decisive: {top.label} and {', '.join(amb)} explain the same part of the "
                "gap; tested again next round)"
            )
        return Decision("named", w, reason, contenders)
    w, ambiguous, contenders = skipped[0]
    by_label = {s.label: s for s in scores}
    tied = [w.label, *ambiguous]
    group = [by_label[lab] for lab in tied]
    advice = _tie_advice(group)
    rep = representative(group)
    reason = (
        f"{' and '.join([', '.join(tied[:-1]), tied[-1]])} explain the same part of the gap (BIC margin < "
        f"{cfg.bic_margin:g}): none is named; to separate them: "
        + ("; ".join(advice) if advice else "collect data that separates them")
    )
    return Decision(
        "ambiguous",
        w,
        reason,
        contenders,
        tied,
        {lab: float(by_label[lab].delta_bic) for lab in tied},
        advice,
        rep,
    )


def representative(group: list[CandidateScore], rtol: float = 1e-6) -> CandidateScore:
    """The member a tie term is evaluated as: the eligible one with the largest dBIC.

    Members within ``rtol`` (relative) of the largest -- an exact tie, where which one leads is a
    matter of rounding -- are ordered by parameter count (the simpler), then by label, so the same
    data always give the same representative. The choice does not change the prediction beyond the
    tie's margin; the term is reported under the whole group's name.
    """
    pool = [s for s in group if s.eligible] or list(group)
    top = max(s.delta_bic for s in pool)
    near = [s for s in pool if s.delta_bic >= top - rtol * max(1.0, abs(top))]
    return min(near, key=lambda s: (s.k + s.k_shape, s.label))


def _tie_advice(tied: list[CandidateScore]) -> list[str]:
    """What separates tied candidates, from their ``tie_advice`` (rival effect name -> advice), deduplicated."""
    out: list[str] = []
    for a in tied:
        table = getattr(a.candidate, "tie_advice", None) or {}
        for b in tied:
            text = table.get(b.name) if b is not a else None
            if text and text not in out:
                out.append(text)
    return out


def gain_given_others(lin: Linearisation, label: str, n_linear: int, values: F64) -> float:
    """BIC gain of one added effect given everything else the current model fits (linearised).

    ``label`` (``name@where``) selects the effect's columns in ``lin`` (``lin.names`` start with
    ``label + "."``: linear parameters first, then shape parameters); ``values`` are its current
    linear parameters. Without the effect its prediction shifts by ``-A_e values`` (exact for the
    linear effects) and the rest is refitted:
    ``gain = M ln(RSS_without / RSS_with) - k ln M`` with ``k`` the effect's parameter count.
    """
    M = lin.residual.size
    A = lin.jacobian.reshape(M, -1)
    w = lin.residual.reshape(-1)
    cols = [i for i, n in enumerate(lin.names) if n.startswith(label + ".")]
    if not cols:
        raise ValueError(f"{label} is not part of the current model")
    rest = [i for i in range(A.shape[1]) if i not in cols]
    y = w + A[:, cols[:n_linear]] @ np.asarray(values, dtype=float)[:n_linear]
    r_without = _perp(_basis(A[:, rest]), y)
    r_with = _perp(_basis(A), w)
    rss_with = max(float(r_with @ r_with), 1e-300)
    return float(M * np.log(float(r_without @ r_without) / rss_with) - len(cols) * np.log(M))
