"""The camera gap's report: the ``vgr.camera_gap_report/1`` document (``--json``, ``camera_gap_report.json``;
JSON Schema ``camera_gap_report.schema.json`` beside this module) and the terminal tables.

Lengths are pixels (``_px``). ``heldout_rms_before_px`` / ``heldout_rms_after_px`` are the k-fold
held-out reprojection RMS of the baseline and of the final model (the figure the workflow shrinks);
``rms_before_px`` / ``rms_after_px`` the in-sample RMS of the fits to all views (OpenCV's RMS);
``board_shape`` (when the board points were released) how far the fitted board lies from the board
as specified, in mm, with the fitted points.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from engine.exit_codes import ExitCode
from engine.plain_data import plain
from plugins.model_gap.camera.catalog import BASELINE, COEFFICIENTS
from plugins.model_gap.camera.fitting import CameraModelFit
from plugins.model_gap.camera.workflow import CameraGapResult, GapRound

__all__ = ["REPORT_FORMAT", "SCHEMA_PATH", "VERDICT_EXIT_CODES", "print_report", "report_dict", "schema"]

REPORT_FORMAT = "vgr.camera_gap_report/1"
SCHEMA_PATH = Path(__file__).with_name("camera_gap_report.schema.json")

#: the same verdict -> exit code table as the robot ``vgr gap`` (plugins/model_gap/cli.py)
VERDICT_EXIT_CODES = {
    "no_gap": ExitCode.OK,
    "explained": ExitCode.OK,
    "explained_up_to_tie": ExitCode.REVIEW,
    "unexplained": ExitCode.NOT_OK,
}


def schema() -> dict[str, Any]:
    """The JSON Schema of the report document."""
    return json.loads(SCHEMA_PATH.read_text())


def _camera(fit: CameraModelFit) -> dict[str, Any]:
    return {
        "fx_px": float(fit.K[0, 0]),
        "fy_px": float(fit.K[1, 1]),
        "cx_px": float(fit.K[0, 2]),
        "cy_px": float(fit.K[1, 2]),
        "free_coefficients": [c for c in COEFFICIENTS if c in fit.free],
        "coefficients": fit.coefficients(),
        "distortion_opencv": [float(x) for x in fit.D],
        "rms_px": fit.rms_px,
    }


def _board_shape(result: CameraGapResult) -> dict[str, Any] | None:
    """How far the released board's points lie from the board as specified (mm), or None."""
    points = result.final_fit.board_points
    if points is None:
        return None
    nominal = result.views[0].object_points
    dz = points[:, 2] - nominal[:, 2]
    dxy = np.linalg.norm(points[:, :2] - nominal[:, :2], axis=1)
    return {
        "out_of_plane_span_mm": float(1e3 * (dz.max() - dz.min())),
        "out_of_plane_rms_mm": float(1e3 * np.sqrt(np.mean((dz - dz.mean()) ** 2))),
        "in_plane_max_mm": float(1e3 * dxy.max()),
        "board_points_m": points.tolist(),
    }


def _round(r: GapRound) -> dict[str, Any]:
    d = r.decision
    return {
        "iteration": r.iteration,
        "current_heldout_rms_px": r.current_heldout_rms_px,
        "candidates": [
            {
                "effect": s.effect.name,
                "coefficients": list(s.effect.coefficients),
                "heldout_rms_px": s.heldout_rms_px,
                "gain_px": s.gain_px,
                "p_value": s.test.p_value,
                "p_corrected": s.p_corrected,
                "n_views_better": s.test.n_better,
                "n_views": s.test.n_views,
                "eligible": s.eligible,
                "reason": s.reason,
            }
            for s in r.scores
        ],
        "decision": {
            "named": None if d.named is None else d.named.name,
            "tied": [e.name for e in d.tie],
            "representative": None if d.representative is None else d.representative.name,
            "parsimony_over": [e.name for e in d.parsimony_over],
            "pair_p_values": d.pair_p_values,
            "reason": d.reason,
        },
    }


def report_dict(
    result: CameraGapResult, rejected: list[dict[str, str]] | None = None, board: str = ""
) -> dict[str, Any]:
    """The ``vgr.camera_gap_report/1`` document of *result* (strict JSON once through ``plain``)."""
    cfg = result.config
    added = [
        {
            "name": a.label,
            "effect": a.effect.name,
            "tied": bool(a.tied_with),
            "members": [e.name for e in (a.effect, *a.tied_with)],
            "parsimony_over": [e.name for e in a.parsimony_over],
            "coefficients": {c: result.final_fit.coefficients().get(c) for c in a.effect.coefficients},
            "iteration": a.iteration,
            "heldout_rms_before_px": a.heldout_rms_before_px,
            "heldout_rms_after_px": a.heldout_rms_after_px,
            "p_corrected": a.p_corrected,
        }
        for a in result.added
    ]
    doc = {
        "format": REPORT_FORMAT,
        "verdict": result.verdict,
        "exit_code": int(VERDICT_EXIT_CODES[result.verdict]),
        "reason": result.reason,
        "notes": list(result.notes),
        "board": board,
        "image_size": list(result.size),
        "n_views": len(result.views),
        "n_corners": int(sum(v.n for v in result.views)),
        "rejected": rejected or [],
        "baseline": sorted(BASELINE, key=COEFFICIENTS.index),
        "named": result.named,
        "effects_added": added,
        "heldout_rms_before_px": result.baseline_cv.rms_px,
        "heldout_rms_after_px": result.final_cv.rms_px,
        "rms_before_px": result.baseline_fit.rms_px,
        "rms_after_px": result.final_fit.rms_px,
        "camera_before": _camera(result.baseline_fit),
        "camera_after": _camera(result.final_fit),
        "board_shape": _board_shape(result),
        "residual_structure": {"before": result.structure_before.to_dict(), "after": result.structure_after.to_dict()},
        "decision_rule": {
            "test": "one-sided Wilcoxon signed-rank over held-out views of MSE_current - MSE_candidate",
            "alpha": cfg.alpha,
            "correction": "bonferroni over the round's candidates",
            "alpha_tie": cfg.alpha_tie,
            "folds": cfg.folds,
            "seed": cfg.seed,
            "max_effects": cfg.max_effects,
            "catalog": [e.name for e in cfg.catalog],
        },
        "iterations": [_round(r) for r in result.rounds],
        "files": {},
    }
    return plain(doc, nan_as_none=True)


def print_report(doc: dict[str, Any], console: Any) -> None:
    """The terminal view of a report document: each round's candidates, what was added, the verdict."""
    from rich.table import Table

    for r in doc["iterations"]:
        t = Table(title=f"round {r['iteration']}: current held-out RMS {r['current_heldout_rms_px']:.4f} px")
        for col in ("effect", "held-out px", "gain px", "views better", "p (corrected)", "eligible"):
            t.add_column(col)
        for c in r["candidates"]:
            t.add_row(
                c["effect"], f"{c['heldout_rms_px']:.4f}", f"{c['gain_px']:+.4f}",
                f"{c['n_views_better']}/{c['n_views']}", f"{c['p_corrected']:.2g}", "yes" if c["eligible"] else "no",
            )  # fmt: skip
        console.print(t)
        console.print(f"  {r['decision']['reason']}", markup=False, highlight=False)
    for e in doc["effects_added"]:
        values = ", ".join(f"{k} = {v:.4g}" for k, v in e["coefficients"].items() if v is not None)
        kind = "tie term, not named" if e["tied"] else "named"
        if e["effect"] == "board_shape" and doc.get("board_shape"):
            b = doc["board_shape"]
            values = f"{b['out_of_plane_span_mm']:.3f} mm out of its plane, {b['in_plane_max_mm']:.3f} mm in it (max)"
        console.print(f"added {e['name']} ({kind}): {values}", markup=False, highlight=False)
    console.print(
        f"held-out reprojection RMS {doc['heldout_rms_before_px']:.4f} -> {doc['heldout_rms_after_px']:.4f} px "
        f"(in-sample {doc['rms_before_px']:.4f} -> {doc['rms_after_px']:.4f} px, {doc['n_views']} views)",
        markup=False,
        highlight=False,
    )
    console.print(f"verdict: {doc['verdict']}: {doc['reason']}", markup=False, highlight=False)
    for note in doc["notes"]:
        console.print(f"note: {note}", markup=False, highlight=False)
