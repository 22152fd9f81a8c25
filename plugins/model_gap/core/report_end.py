"""The report's second-round sections: the samples left out as gross errors, and the honest end.

``outliers`` (:func:`outliers_dict`): the screen's figures (:mod:`.robust`) with every sample left out
by its row and its residual under the final model. ``end_test`` (:func:`end_dict`): whether structure
is left after the last named effect and against which references (:mod:`.end_test`), where it
concentrates (the strongest significant designs, per error direction and per feature), the share rule
(:mod:`.share`: each term's share of what is left, its BIC gain given the structure, what was taken out)
and the campaign to measure when the verdict is ``unexplained``. :func:`print_end` prints both.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape

if TYPE_CHECKING:
    from plugins.model_gap.core.workflow import GapResult


def outliers_dict(result: GapResult) -> dict[str, Any] | None:
    """``outliers``: None when no screen ran (``outlier_alpha`` 0)."""
    sc = result.outliers
    if sc is None:
        return None
    s, u = result.report_scale, result.report_unit
    return {
        "n_samples": sc.n_samples,
        "n_left_out": sc.n_flagged,
        "alpha_familywise": sc.alpha,
        "cut_sigma": float(sc.cut**0.5),
        "robust_scale": sc.scale,
        "passes": sc.passes,
        "stable": sc.stable,
        "samples": [
            {"row": i, f"residual_{u}": r * s, "over_robust_scale": x}
            for i, r, x in zip(sc.ids, sc.residual, sc.ratio, strict=True)
        ],
        "why": sc.describe(u, s),
        "notes": list(sc.notes),
    }


def _where(result: GapResult) -> dict[str, Any]:
    st = result.iterations[-1].structure
    sig = [] if st is None else st.significant
    joints: dict[str, float] = {}
    features: dict[str, float] = {}
    for f in sig:
        if "~" in f.design:
            joint, feat = f.design.split("~", 1)
            joints[joint] = min(joints.get(joint, 1.0), f.p_corrected)
            features[feat] = min(features.get(feat, 1.0), f.p_corrected)
        elif f.design.startswith("feature:"):
            features[f.design[8:]] = min(features.get(f.design[8:], 1.0), f.p_corrected)
    return {
        "designs": [
            {"design": f.design, "label": f.label, "f_stat": f.f_stat, "p_corrected": f.p_corrected} for f in sig[:5]
        ],
        "joints": dict(sorted(joints.items(), key=lambda kv: kv[1])),
        "features": dict(sorted(features.items(), key=lambda kv: kv[1])),
    }


def end_dict(result: GapResult) -> dict[str, Any]:
    """``end_test``: structure left, the references used, where it concentrates, the share rule, the advice."""
    st = result.iterations[-1].structure
    cfg = result.config
    share = result.share
    return {
        "structure_left": bool(st is not None and st.found),
        "references": {
            "replicates": st is not None and st.pure_error_variance is not None,
            "stated_noise_trusted_to": None if st is None else st.noise_trust,
            "held_out_structure_designs": 0 if st is None else st.n_tests,
        },
        "where": _where(result),
        "share_rule": None
        if share is None
        else {
            "min_share": cfg.min_share,
            "margin": share.margin,
            "noise_reference": share.reference,
            "left_fraction_of_rss": share.left_fraction,
            "shares": share.shares,
            "gain_given_structure": share.gain_given_structure,
            "dropped": [{"effect": lab, "share": x} for lab, x in share.dropped],
        },
        "campaign": list(result.advice),
    }


def print_end(result: GapResult, console: Console) -> None:
    """The terminal lines of both sections (nothing when there is nothing to say)."""
    sc = result.outliers
    if sc is not None and sc.ids:
        console.print(f"[yellow]gross errors:[/] {escape(sc.describe(result.report_unit, result.report_scale))}",
                      soft_wrap=True)  # fmt: skip
    share = result.share
    if share is not None and share.dropped:
        for lab, _ in share.dropped:
            console.print(f"[yellow]share rule:[/] taken out {escape(share.why(lab))}", soft_wrap=True)
    for tip in result.advice:
        console.print(f"[cyan]to find what is missing:[/] {escape(tip)}", soft_wrap=True)
