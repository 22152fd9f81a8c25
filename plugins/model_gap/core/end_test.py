"""The honest end: is structure left after the last named effect, judged without the residuals' own noise?

The loop stops when no catalog effect is decisive. What is left must then be tested against a noise
level the residuals did not produce themselves -- else an effect outside the catalog is absorbed into
an "estimated noise" 2.5x the instrument's and nothing flags it. This module owns the designs and
tests that :func:`plugins.model_gap.core.structure.residual_structure` adds to its per-feature bins and
smooth field (all Bonferroni together at the family-wise ``alpha``):

* **error directions x features** (held-out structure along every feature): a problem may give
  *error directions* ``d_j`` (``(N, m)``, e.g. the tool point's displacement per radian of joint
  ``j``'s angle error). An error the catalog lacks is ``d_j g(x)`` for some smooth function ``g`` of a
  feature ``x`` -- a cable pulling on the wrist makes joint 6's error follow joint 5's angle. For
  every direction and every feature the design ``d_j phi_b(x)`` (``phi``: 1, x, x^2, x^3 of the
  standardised feature; for an angle also sin, cos, sin 2x, cos 2x; for a categorical feature one
  indicator per level) is F-tested against a constant-free residual (``span(A)`` projected out)::

      F = ((RSS_0 - RSS_X) / k) / (RSS_X / (M - rank A - k))

  The denominator is the residual scale *outside* the design, so a structured residual is not
  mistaken for noise; the test is exact for a linear Gaussian model whatever the noise level.
* **replicates** (:func:`replicate_finding`): rows measured at the same pose give a pure-error sum
  of squares that no model can reach (within-group deviations); the classical lack-of-fit F-test
  ``F = (SS_lof / df_lof) / (SS_pe / df_pe)`` compares the model's residual with it.
* **the instrument's stated noise** (:func:`stated_noise_finding`, when the noise was given, not
  estimated): the residual variance against ``noise_trust^2`` times the stated one, chi-square on
  ``M - rank A`` dof. The stated noise is trusted to a factor ``noise_trust`` (default 2): within it a
  misstated noise changes only the noise check, beyond it the excess is a gap.

:func:`campaign_advice` turns where the structure concentrates into what to measure next.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from plugins.model_gap.core.interfaces import F64, Feature, Linearisation

DEFAULT_NOISE_TRUST = 2.0
#: what a user should measure when the residuals are left unexplained and the campaign has no replicates
REPLICATE_ADVICE = (
    "measure replicate poses: the same pose 5-10 times back to back at ~10 poses spread over the workspace "
    "(the noise is then known without any model, and what the model leaves above it is the gap)"
)


def _feature_basis(f: Feature) -> F64 | None:
    """``(N, b)`` smooth functions of the feature (module docstring), or None when it does not vary."""
    v = np.asarray(f.values, dtype=float)
    if f.categorical:
        levels = np.unique(v)
        return None if levels.size < 2 else np.column_stack([(v == lv).astype(float) for lv in levels])
    sd = float(v.std())
    if not sd > 0:
        return None
    x = (v - v.mean()) / sd
    cols = [np.ones_like(x), x, x**2, x**3]
    if f.unit == "deg":
        r = np.radians(v)
        cols += [np.sin(r), np.cos(r), np.sin(2 * r), np.cos(2 * r)]
    return np.column_stack(cols)


def direction_designs(
    lin: Linearisation, directions: list[tuple[str, str, F64]], features: list[Feature]
) -> list[tuple[str, str, F64]]:
    """``(key, label, (M, k) whitened design)`` per error direction and feature: ``jointJ~q5`` ..."""
    N, m = lin.residual.shape
    out = []
    for name, label, d in directions:
        d = np.asarray(d, dtype=float)
        if d.shape != (N, m) or not np.all(np.isfinite(d)):
            continue
        dw = d / lin.sigma[:, None]
        for f in features:
            if f.values.shape != (N,) or not np.all(np.isfinite(f.values)):
                continue
            basis = _feature_basis(f)
            if basis is None:
                continue
            X = (dw[:, :, None] * basis[:, None, :]).reshape(N * m, -1)
            out.append((f"{name}~{f.name}", f"{label} as a function of {f.label}", X))
    return out


def replicate_finding(w_perp: F64, m: int, groups: list[np.ndarray], dof_total: int) -> tuple[float, int, float] | None:
    """``(F, df_pe, pure-error variance)`` of the lack-of-fit test, or None without enough replicates.

    ``w_perp`` ``(M,)``: the whitened residual with the model's span projected out (samples x
    components, sample-major); ``dof_total = M - rank A``. The returned F is on ``(df_lof, df_pe)``.
    """
    W = w_perp.reshape(-1, m)
    ss_pe, df_pe = 0.0, 0
    for g in groups:
        r = W[g]
        ss_pe += float(np.sum((r - r.mean(axis=0)) ** 2))
        df_pe += (len(g) - 1) * m
    df_lof = dof_total - df_pe
    if df_pe < 3 or df_lof < 1 or ss_pe <= 0:
        return None
    ss_lof = max(float(w_perp @ w_perp) - ss_pe, 0.0)
    return (ss_lof / df_lof) / (ss_pe / df_pe), df_pe, ss_pe / df_pe


def stated_noise_finding(rss: float, dof: int, trust: float) -> tuple[float, float]:
    """``(variance ratio over trust^2, p)``: residuals above ``trust`` x the stated noise (chi-square)."""
    dof = max(1, int(dof))
    return (rss / dof) / trust**2, float(stats.chi2.sf(rss / trust**2, dof))


def _feature_words(name: str, label: str) -> str:
    if name.startswith("q") and name[1:].isdigit():
        return f"joint {name[1:]} over its range with the other joints held at a few poses"
    if name.startswith("tau") or name == "payload_kg":
        return f"the load ({label}): measure the same poses with and without a payload"
    if name in ("t_s", "temp_c"):
        return f"{label}: repeat a few poses over the warm-up and log the temperature near the joints"
    if name.startswith("dir"):
        return f"{label}: reach the same poses from both sides"
    return label


def campaign_advice(findings: list, has_replicates: bool, top: int = 3) -> list[str]:
    """What to measure next from the significant structure findings (strongest first)."""
    out: list[str] = []
    for f in findings[:top]:
        key = f.design
        if "~" in key:
            joint, feat = key.split("~", 1)
            words = _feature_words(feat, f.label.split(" as a function of ", 1)[-1])
            out.append(
                f"sweep {words}, measuring the tool point: {joint.replace('joint', 'joint ')}'s error follows it "
                "(a coupling the catalog lacks, e.g. a cable or hose pulling on the joint)"
            )
        elif key.startswith("feature:"):
            out.append(f"sweep {_feature_words(key[8:], f.label.split('along ', 1)[-1])} and log it with every sample")
        elif key == "field":
            out.append(
                "measure a reference artefact (a calibrated scale bar or points) across the workspace with the "
                "same instrument: a smooth field over the workspace is the instrument or the cell, not the robot"
            )
        elif key == "stated_noise":
            out.append("check the instrument's noise: " + REPLICATE_ADVICE)
    if not has_replicates and REPLICATE_ADVICE not in " ".join(out):
        out.append(REPLICATE_ADVICE)
    return list(dict.fromkeys(out))
