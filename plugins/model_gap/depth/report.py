"""The depth gap's report: the ``vgr.depth_gap_report/1`` document (``--json``, ``depth_gap_report.json``;
JSON Schema ``depth_gap_report.schema.json`` beside this module) and the terminal tables.

Lengths are millimetres (``_mm``): ``heldout_rms_before_mm`` / ``heldout_rms_after_mm`` are the k-fold
held-out RMS range error per pixel of the baseline and of the final model (the figure the workflow
shrinks), ``rms_before_mm`` / ``rms_after_mm`` the in-sample RMS of the fits to all captures. Each
added effect's coefficients are in its catalog unit (``unit``: ppm, mm, mm/m^2); ``share`` is the part
of what the model without it left beyond the noise that it explains, ``dropped`` whether it was taken
out again (structure left, share below ``min_share``). ``gross_errors`` counts the flying pixels left
out, ``captures`` each capture's pixels, flagged pixels, depth, noise and held-out RMS before / after.
Strict JSON: a value that is not finite is ``null``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from engine.plain_data import plain
from plugins.model_gap import gap_report_parts as parts
from plugins.model_gap.depth.catalog import report_values
from plugins.model_gap.depth.workflow import AddedTerm, DepthGapResult, GapRound
from plugins.model_gap.verdicts import VERDICT_EXIT_CODES  # re-exported: the table of every gap workflow

__all__ = ["REPORT_FORMAT", "SCHEMA_PATH", "VERDICT_EXIT_CODES", "print_report", "report_dict", "schema"]

REPORT_FORMAT = "vgr.depth_gap_report/1"
SCHEMA_PATH = Path(__file__).with_name("depth_gap_report.schema.json")

_BASELINE = {
    "known": "the range each pixel's ray meets the target's known plane at (no free coefficient)",
    "fit": "the range each pixel's ray meets its capture's plane at, the plane fitted per capture (3 per capture)",
}


def schema() -> dict[str, Any]:
    """The JSON Schema of the report document."""
    return parts.load_schema(SCHEMA_PATH)


def _round(r: GapRound) -> dict[str, Any]:
    d = r.decision
    return {
        "iteration": r.iteration,
        "current_heldout_rms_mm": r.current_heldout_rms_mm,
        "candidates": [
            {
                "effect": s.effect.name,
                "coefficients": list(s.effect.coefficients),
                "heldout_rms_mm": s.heldout_rms_px,  # (the camera selection's field: here in mm)
                "gain_mm": s.gain_px,
                "p_value": s.test.p_value,
                "p_corrected": s.p_corrected,
                "n_captures_better": s.test.n_better,
                "n_captures": s.test.n_views,
                "eligible": s.eligible,
                "reason": s.reason.replace("held-out views", "held-out captures"),
            }
            for s in r.scores
        ],
        "decision": parts.decision_dict(
            d,
            d.reason.replace("held-out views", "held-out captures").replace(
                "views near the image corners and strongly tilted separate them",
                "captures over a wider range of distances and tilts, the target filling the image, separate them",
            ),
        ),
    }


def _added(a: AddedTerm, result: DepthGapResult) -> dict[str, Any]:
    if a.dropped:
        coefficients: dict[str, float | None] = dict.fromkeys(a.effect.coefficients)
    else:
        coefficients = dict(report_values(a.effect, result.final_fit.theta_of(a.effect)))
    return {
        **parts.term_names(a),
        "coefficients": coefficients,
        "unit": a.effect.unit,
        "description": a.effect.description,
        "iteration": a.iteration,
        "heldout_rms_before_mm": a.heldout_rms_before_mm,
        "heldout_rms_after_mm": a.heldout_rms_after_mm,
        "p_corrected": a.p_corrected,
        "share": a.share,
        "dropped": a.dropped,
    }


def _captures(result: DepthGapResult) -> list[dict[str, Any]]:
    px = result.pixels
    before, after = result.baseline_cv, result.final_cv
    per = {c["capture"]: c for c in result.noise["per_capture"]}
    flagged = result.flagged_per_capture or [0] * px.n_captures
    out = []
    for k, name in enumerate(px.names):
        n = max(int(before.n_points[k]), 1)
        out.append(
            {
                "name": name,
                "n_pixels": int(before.n_points[k]),
                "n_flagged": int(flagged[k]),
                "median_depth_mm": per[name]["median_depth_mm"],
                "sigma_mm": per[name]["sigma_mm"],
                "heldout_rms_before_mm": float(1e3 * np.sqrt(before.sse[k] / n)),
                "heldout_rms_after_mm": float(1e3 * np.sqrt(after.sse[k] / n)),
            }
        )
    return out


def report_dict(
    result: DepthGapResult, rejected: list[dict[str, str]] | None = None, source: str = ""
) -> dict[str, Any]:
    """The ``vgr.depth_gap_report/1`` document of *result* (strict JSON once through ``plain``)."""
    cfg, sc, px = result.config, result.screen, result.pixels
    noise = {k: v for k, v in result.noise.items() if k != "per_capture"}
    doc = {
        **parts.report_head(REPORT_FORMAT, result),
        "source": source,
        "target": px.target,
        "image_size": list(px.size),
        "n_captures": px.n_captures,
        "n_pixels": len(px.capture),
        "rejected": rejected or [],
        "baseline": _BASELINE[px.target],
        "untested": [{"effect": k, "identifiable_share": v} for k, v in result.untestable.items()],
        "gross_errors": {
            "n_flagged": sc.n_flagged,
            "n_screened": len(sc.inlier),
            "threshold_sigma": sc.threshold_sigma,
            "outlier_alpha": sc.alpha,
        },
        "noise": noise,
        "named": result.named,
        "effects_added": [_added(a, result) for a in result.added],
        "heldout_rms_before_mm": result.baseline_cv.rms_mm,
        "heldout_rms_after_mm": result.final_cv.rms_mm,
        "rms_before_mm": result.rms_before_mm,
        "rms_after_mm": result.rms_after_mm,
        "captures": _captures(result),
        "residual_structure": {"before": result.structure_before.to_dict(), "after": result.structure_after.to_dict()},
        "decision_rule": parts.decision_rule(
            cfg,
            "captures",
            min_share=cfg.min_share,
            noise_trust=cfg.noise_trust,
            wiggle_period_mm=1e3 * cfg.wiggle_period_m,
        ),
        "iterations": [_round(r) for r in result.rounds],
        "files": {},
    }
    return plain(doc, nan_as_none=True)


def print_report(doc: dict[str, Any], console: Any) -> None:
    """The terminal view of a report document: each round's candidates, what was added, the verdict."""
    parts.print_rounds(doc, console, "mm", "captures")
    for e in doc["effects_added"]:
        values = ", ".join(f"{k} = {v:.4g}" for k, v in e["coefficients"].items() if v is not None)
        kind = "tie term, not named" if e["tied"] else "named"
        share = "" if e["share"] is None else f", share {e['share']:.0%}"
        gone = "; taken out again" if e["dropped"] else ""
        parts.say(console, f"added {e['name']} ({kind}): {values or '-'}{share}{gone}")
    g = doc["gross_errors"]
    if g["n_flagged"]:
        parts.say(
            console,
            f"gross errors: {g['n_flagged']} of {g['n_screened']} pixels left out (> {g['threshold_sigma']:.1f} sigma)",
        )
    parts.say(
        console,
        f"held-out range RMS {doc['heldout_rms_before_mm']:.4f} -> {doc['heldout_rms_after_mm']:.4f} mm "
        f"(in-sample {doc['rms_before_mm']:.4f} -> {doc['rms_after_mm']:.4f} mm, {doc['n_captures']} captures, "
        f"{doc['n_pixels']} pixels, target {doc['target']})",
    )
    parts.print_verdict(doc, console)
