"""How the ``camera_gap`` and ``depth_gap`` stages end: the ``failed`` result when the workflow
refuses its input, the report file in the stage's folder, and the ``result`` event and
CalibrationResult message of a verdict."""

from __future__ import annotations

import json
from typing import Any

from engine.messages import CalibrationResultMsg
from plugins.model_gap.gap_report_parts import write_report_file

__all__ = ["publish_failed", "publish_verdict", "write_report"]


def publish_failed(ctx: Any, kind: str, exc: Exception) -> None:
    """A ``<kind>_failed`` warning and a ``failed`` result with *exc* as its reason (not a failed run)."""
    ctx.event("warning", f"{kind}_failed", str(exc))
    ctx.publish("result", CalibrationResultMsg(kind=kind, verdict="failed", reasons=[str(exc)]))


def write_report(ctx: Any, report_dir: str | None, file_name: str, doc: dict[str, Any]) -> dict[str, str]:
    """Write *doc* as *file_name* in the stage's folder (or *report_dir*), naming it in ``doc["files"]``;
    the files written (none without a folder)."""
    folder = ctx.output_dir(report_dir)
    if folder is None:
        return {}
    files = {"report": str(folder / file_name)}
    doc["files"] = dict(files)
    write_report_file(folder / file_name, doc)
    return files


def publish_verdict(
    ctx: Any,
    kind: str,
    result: Any,
    doc: dict[str, Any],
    *,
    text: str,
    method: str,
    metrics: dict[str, float],
    files: dict[str, str],
) -> None:
    """The ``result`` event (*text*) and the CalibrationResult of *result*'s verdict, *doc* as its JSON."""
    ctx.event("result", kind, text, verdict=result.verdict, files=files)
    ctx.publish(
        "result",
        CalibrationResultMsg(
            kind=kind,
            verdict=result.verdict,
            method=method,
            reasons=[result.reason],
            metrics=metrics,
            result_json=json.dumps(doc, allow_nan=False),
        ),
    )
