"""Model-gap figures (PNG, matplotlib Agg): the gap before / after, and each effect's signature.

* ``gap_histograms.png``: whitened residual components of the model as given and of the augmented
  model against the unit normal the noise specification predicts, and the 3-D error norms;
* ``gap_rounds.png``: held-out RMS after each round against the noise floor, and the RMS per bin of
  the features where the gap concentrated most (first model vs augmented model);
* ``gap_effect_<n>_<name>_<where>.png`` (a tie term: ``gap_effect_<n>_tie_<a>_<x>_or_<b>_<y>.png``,
  drawn as its representative): for each added effect, the calibrated residual expressed in the
  effect's own quantity (e.g. joint error in urad) against its regressor (gravity torque, approach
  direction, time, speed, range ...), before and after adding it, with the part of the fitted effect
  the calibration cannot absorb (the part the residuals can show; :class:`EffectSeries`);
* ``check_plots.png`` (``vgr gap check``): a stored model's residuals on new data (:func:`plot_check`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from plugins.model_gap.core.check import ModelCheck
from plugins.model_gap.core.interfaces import Feature
from plugins.model_gap.core.iteration import Iteration
from plugins.model_gap.core.localise import FeatureGap
from plugins.model_gap.core.report import display
from plugins.model_gap.core.workflow import GapResult


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_histograms(result: GapResult, path: Path) -> Path:
    plt = _plt()
    s, u = result.report_scale, result.report_unit
    first, last = result.iterations[0], result.iterations[-1]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    lim = max(4.0, float(np.percentile(np.abs(first.whitened), 99.5)))
    bins = np.linspace(-lim, lim, 61)
    ax.hist(first.whitened.ravel(), bins, density=True, alpha=0.5, label="model as given (+ calibration)")
    ax.hist(last.whitened.ravel(), bins, density=True, alpha=0.5, label="augmented model")
    x = np.linspace(-lim, lim, 300)
    ax.plot(x, stats.norm.pdf(x), "k--", label="noise spec N(0, 1)")
    ax.set_xlabel("residual / noise sigma (per axis)")
    ax.set_ylabel("density")
    ax.legend(fontsize=8)
    ax.set_title("whitened residuals")
    ax = axes[1]
    n0 = np.linalg.norm(first.residual, axis=1) * s
    n1 = np.linalg.norm(last.residual, axis=1) * s
    hi = float(np.percentile(n0, 99.5)) * 1.05
    bins = np.linspace(0, hi, 50)
    ax.hist(n0, bins, alpha=0.5, label=f"before: RMS {first.comparison.rms * s:.3f} {u}")
    ax.hist(n1, bins, alpha=0.5, label=f"after: RMS {last.comparison.rms * s:.3f} {u}")
    sig = first.comparison.noise_rms / np.sqrt(first.residual.shape[1]) * s
    xx = np.linspace(0, hi, 300)
    ax.plot(xx, stats.chi.pdf(xx / sig, first.residual.shape[1]) / sig * len(n0) * (bins[1] - bins[0]), "k--",
            label="noise alone")  # fmt: skip
    ax.set_xlabel(f"3-D error ({u})")
    ax.set_ylabel("samples")
    ax.legend(fontsize=8)
    ax.set_title("error per sample")
    fig.suptitle(f"vgr gap: {result.verdict}", fontsize=10)
    return _save(fig, path)


def plot_rounds(result: GapResult, features: list[Feature], path: Path) -> Path:
    plt = _plt()
    s, u = result.report_scale, result.report_unit
    first, last = result.iterations[0], result.iterations[-1]
    top = first.localisation[:3]
    fig, axes = plt.subplots(1, 1 + len(top), figsize=(4 * (1 + len(top)), 3.6))
    axes = np.atleast_1d(axes)
    ax = axes[0]
    labels = ["as given"] + [
        f"+{it.added.label}" + (" (tie)" if it.added.tied else "") for it in result.iterations if it.added
    ]
    vals = [it.comparison.cv_rms * s for it in result.iterations][: len(labels)]
    ax.bar(range(len(vals)), vals, color="tab:blue")
    ax.axhline(first.comparison.noise_rms * s, color="k", ls="--", label="noise floor")
    ax.axhline(1.2 * first.comparison.noise_rms * s, color="grey", ls=":", label="1.2 x floor")
    ax.set_xticks(range(len(vals)), labels, rotation=20, ha="right", fontsize=7)
    ax.set_ylabel(f"held-out RMS ({u})")
    ax.legend(fontsize=7)
    for ax, g, masks in _group_panels(axes[1:], top, features):
        before, after = _rms_per_bin(first.residual, masks, s), _rms_per_bin(last.residual, masks, s)
        xb = np.arange(len(masks))
        ax.bar(xb - 0.2, before, 0.4, label="as given")
        ax.bar(xb + 0.2, after, 0.4, label="augmented")
        ax.axhline(first.comparison.noise_rms * s, color="k", ls="--")
        _label_bins(ax, g, u)
    return _save(fig, path)


def _group_panels(
    axes: Any, groups: list[FeatureGap], features: list[Feature]
) -> Iterator[tuple[Any, FeatureGap, list[np.ndarray]]]:
    """(axis, group, one mask of the samples per bin) for the groups side by side with *axes*; a
    group whose feature is not in *features* leaves its axis empty."""
    by_name = {f.name: f for f in features}
    for ax, g in zip(axes, groups, strict=False):
        f = by_name.get(g.name)
        if f is not None:
            yield ax, g, _masks(f, [b.label for b in g.bins])


def _label_bins(ax: Any, g: FeatureGap, unit: str) -> None:
    """Bin labels, title and legend of a panel of RMS per bin of group *g* (RMS in *unit*)."""
    ax.set_xticks(np.arange(len(g.bins)), [b.label for b in g.bins], rotation=20, ha="right", fontsize=7)
    ax.set_title(f"{g.label} ({g.unit})" if g.unit else g.label, fontsize=9)
    ax.set_ylabel(f"RMS ({unit})")
    ax.legend(fontsize=7)


def _rms_per_bin(residual: np.ndarray, masks: list[np.ndarray], scale: float) -> list[float]:
    """3-D RMS of the (N, 3) *residual* in each bin, in report units (*scale* per metre)."""
    return [float(np.sqrt(np.mean(np.sum(residual[m] ** 2, axis=1)))) * scale for m in masks]


def _masks(f: Feature, labels: list[str]) -> list[np.ndarray]:
    v = f.values
    out = []
    for lab in labels:
        if ".." in lab and not f.categorical:
            lo, hi = (float(x) for x in lab.split(".."))
            out.append((v >= lo) & (v <= hi))
        else:
            out.append(np.isclose(v, float(lab)))
    return out


@dataclass
class EffectSeries:
    """What ``gap_effect_*.png`` draws for one added effect (every array per sample, display units).

    ``y_*`` are residuals expressed in the effect's own quantity (see :class:`Signature`): before the
    effect was added (that round's calibrated model), with the final model, and the fitted effect's
    *identifiable part* -- its contribution with the span of the model before it projected out, i.e.
    what the calibrated residuals can show. The full contribution (``y_full``) is not drawn: most of
    an effect like ``depth_scale`` is absorbed by the frame calibration, and a line at the full effect
    would sit far from the residuals it is meant to explain. ``identifiable_share`` is the RMS of the
    identifiable part over the RMS of the full contribution.
    """

    x: np.ndarray
    x_label: str
    y_before: np.ndarray
    y_final: np.ndarray
    y_fitted: np.ndarray
    y_full: np.ndarray
    y_label: str
    unit: str
    mask: np.ndarray  # samples where the effect has leverage (plotted)
    identifiable_share: float


def effect_series(result: GapResult, it: Iteration) -> EffectSeries | None:
    """The series of :func:`plot_effect` for the effect added in round ``it`` (None: nothing to plot)."""
    sig, c, ci = it.signature, it.contribution, it.identifiable
    if sig is None or c is None or ci is None or it.added is None:
        return None
    if sig.basis is not None:
        basis, unit, label = sig.basis, sig.y_unit, sig.y_label or "residual along the effect"
    else:  # several parameters, no scalar quantity: the fraction of the fitted (identifiable) effect
        basis, unit, label = ci, "", "residual along the fitted effect"
    norm2 = np.sum(basis**2, axis=1)
    ok = norm2 > 0.05 * np.median(norm2)  # samples where the effect has leverage

    def y(r: np.ndarray) -> np.ndarray:
        return np.sum(basis * r, axis=1) / np.where(ok, norm2, 1.0)

    f, dunit = display(1.0, unit) if unit else (1.0, "fraction of the fitted effect")
    full = float(np.sqrt(np.mean(np.sum(c**2, axis=1))))
    share = float(np.sqrt(np.mean(np.sum(ci**2, axis=1))) / full) if full > 0 else 0.0
    last = result.iterations[-1]
    return EffectSeries(
        sig.x.copy(),
        sig.x_label,
        y(it.residual) * f,
        y(last.residual) * f,
        y(ci) * f,
        y(c) * f,
        label,
        dunit,
        ok,
        share,
    )


def plot_effect(result: GapResult, it: Iteration, path: Path) -> Path | None:
    """Residual vs the effect's regressor, before (this round) and after (final model), with the part
    of the fitted effect the residuals can show (:class:`EffectSeries`)."""
    es = effect_series(result, it)
    if es is None or it.added is None:
        return None
    plt = _plt()
    ok = es.mask
    x = es.x.copy()
    if np.unique(x).size <= 3:  # categorical (approach direction): jitter
        x = x + np.random.default_rng(0).uniform(-0.08, 0.08, x.size) * max(1.0, np.ptp(x))
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(x[ok], es.y_before[ok], ".", color="tab:orange", alpha=0.6, label="before adding it")
    ax.plot(x[ok], es.y_final[ok], ".", color="tab:blue", alpha=0.6, label="final model")
    fitted = "fitted effect"
    if es.identifiable_share < 0.95:
        fitted += f": the part the calibration cannot absorb ({100 * es.identifiable_share:.0f} % of its RMS)"
    ax.plot(x[ok], es.y_fitted[ok], "k.", ms=3, label=fitted)
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlabel(es.x_label)
    ax.set_ylabel(f"{es.y_label} ({es.unit})")
    title = f"{it.added.label}: calibrated residual against its regressor"
    if it.added.tied:  # a tie term: the group, evaluated as its representative, is not a named effect
        title = (
            f"tie term {it.added.label}: calibrated residual against its regressor\n"
            f"(not a named effect; evaluated as {it.added.representative})"
        )
    ax.set_title(title, fontsize=9 if it.added.tied else 10)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_check(c: ModelCheck, features: list[Feature], path: Path) -> Path:
    """``check_plots.png`` of ``vgr gap check``: the stored model's whitened residuals on the new data
    against N(0, 1), the 3-D errors against the chi distribution of the noise (scaled by the model's
    expected factor), and the RMS per bin of the features where the residuals concentrate most."""
    plt = _plt()
    s, u = c.report_scale, c.report_unit
    top = c.localisation[:2]
    fig, axes = plt.subplots(1, 2 + len(top), figsize=(4.2 * (2 + len(top)), 3.8))
    ax = axes[0]
    lim = max(4.0, float(np.percentile(np.abs(c.whitened), 99.5)))
    bins = np.linspace(-lim, lim, 61)
    ax.hist(c.whitened.ravel(), bins, density=True, alpha=0.6, label="stored model, new data")
    x = np.linspace(-lim, lim, 300)
    ax.plot(x, stats.norm.pdf(x), "k--", label="noise spec N(0, 1)")
    ax.set_xlabel("residual / noise sigma (per axis)")
    ax.legend(fontsize=8)
    ax.set_title("whitened residuals")
    ax = axes[1]
    m = c.residual.shape[1]
    norms = np.linalg.norm(c.residual, axis=1) * s
    hi = float(np.percentile(norms, 99.5)) * 1.05
    edges = np.linspace(0, hi, 50)
    ax.hist(norms, edges, alpha=0.6, label=f"RMS {c.rms * s:.3f}, max {c.max * s:.3f} {u}")
    sig = c.noise_floor / np.sqrt(m) * c.expected_factor * s
    xx = np.linspace(0, hi, 300)
    ax.plot(xx, stats.chi.pdf(xx / sig, m) / sig * len(norms) * (edges[1] - edges[0]), "k--",
            label="a correct model")  # fmt: skip
    ax.set_xlabel(f"3-D error ({u})")
    ax.legend(fontsize=8)
    ax.set_title("error per sample")
    for ax, g, masks in _group_panels(axes[2:], top, features):
        vals = _rms_per_bin(c.residual, masks, s)
        ax.bar(np.arange(len(vals)), vals)
        ax.axhline(c.expected_rms * s, color="k", ls="--", label="expected")
        _label_bins(ax, g, u)
    fig.suptitle(f"vgr gap check: {c.verdict}", fontsize=10)
    return _save(fig, path)


def _save(fig: Any, path: Path) -> Path:
    """Write figure *fig* to *path* (laid out, 100 dpi) and free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    _plt().close(fig)
    return path
