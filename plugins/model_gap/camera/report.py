"""The camera gap's report: the ``vgr.camera_gap_report/1`` document (``--json``, ``camera_gap_report.json``;
JSON Schema ``camera_gap_report.schema.json`` beside this module) and the terminal tables.

Lengths are pixels (``_px``). ``heldout_rms_before_px`` / ``heldout_rms_after_px`` are the k-fold
held-out reprojection RMS of the baseline and of the final model (the figure the workflow shrinks);
``rms_before_px`` / ``rms_after_px`` the in-sample RMS of the fits to all views (OpenCV's RMS);
``board_shape`` (when the board points were released) how far the fitted board lies from the board
as specified, in mm, with the fitted points.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from engine.plain_data import plain
from plugins.model_gap import gap_report_parts as parts
from plugins.model_gap.camera.catalog import BASELINE, COEFFICIENTS
from plugins.model_gap.camera.fitting import CameraModelFit
from plugins.model_gap.camera.workflow import CameraGapResult, GapRound
from plugins.model_gap.verdicts import VERDICT_EXIT_CODES  # re-exported: the table of every gap workflow

__all__ = ["REPORT_FORMAT", "SCHEMA_PATH", "VERDICT_EXIT_CODES", "print_report", "report_dict", "schema"]

REPORT_FORMAT = "vgr.camera_gap_report/1"
SCHEMA_PATH = Path(__file__).with_name("camera_gap_report.schema.json")


def schema() -> dict[str, Any]:
    """The JSON Schema of the report document."""
    return parts.load_schema(SCHEMA_PATH)


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
        "decision": parts.decision_dict(d, d.reason),
    }


def report_dict(
    result: CameraGapResult, rejected: list[dict[str, str]] | None = None, board: str = ""
) -> dict[str, Any]:
    """The ``vgr.camera_gap_report/1`` document of *result* (strict JSON once through ``plain``)."""
    cfg = result.config
    added = [
        {
            **parts.term_names(a),
            "coefficients": {c: result.final_fit.coefficients().get(c) for c in a.effect.coefficients},
            "iteration": a.iteration,
            "heldout_rms_before_px": a.heldout_rms_before_px,
            "heldout_rms_after_px": a.heldout_rms_after_px,
            "p_corrected": a.p_corrected,
        }
        for a in result.added
    ]
    doc = {
        **parts.report_head(REPORT_FORMAT, result),
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
        "decision_rule": parts.decision_rule(cfg, "views"),
        "iterations": [_round(r) for r in result.rounds],
        "files": {},
    }
    return plain(doc, nan_as_none=True)


def print_report(doc: dict[str, Any], console: Any) -> None:
    """The terminal view of a report document: each round's candidates, what was added, the verdict."""
    parts.print_rounds(doc, console, "px", "views")
    for e in doc["effects_added"]:
        values = ", ".join(f"{k} = {v:.4g}" for k, v in e["coefficients"].items() if v is not None)
        kind = "tie term, not named" if e["tied"] else "named"
        if e["effect"] == "board_shape" and doc.get("board_shape"):
            b = doc["board_shape"]
            values = f"{b['out_of_plane_span_mm']:.3f} mm out of its plane, {b['in_plane_max_mm']:.3f} mm in it (max)"
        parts.say(console, f"added {e['name']} ({kind}): {values}")
    parts.say(
        console,
        f"held-out reprojection RMS {doc['heldout_rms_before_px']:.4f} -> {doc['heldout_rms_after_px']:.4f} px "
        f"(in-sample {doc['rms_before_px']:.4f} -> {doc['rms_after_px']:.4f} px, {doc['n_views']} views)",
    )
    parts.print_verdict(doc, console)
