"""Calibration results for people: the text report (mm, degrees) and the report directory.

:func:`format_result` renders any :class:`CalibrationResult`: the hand-eye / robot-world report of
:mod:`plugins.calibration.handeye.report` for those kinds, otherwise a generic one built on
:meth:`CalibrationResult.summary_rows` (estimate with 1-sigma), the metrics, a per-sample residual
table, the verdict with its reasons and advice. :func:`write_report_dir` writes ``result.json``
(``CalibrationResult.to_dict``), ``report.txt`` (the text report) and ``summary.md`` (verdict, the
summary rows as a Markdown table, metrics, reasons, advice, extra sections such as the kinematic
before/after table); callers add their own files (e.g. the kinematic convergence PNG).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from engine.files import replace_text
from plugins.calibration.handeye.report import format_report as format_hand_eye_report
from plugins.calibration.result import CalibrationResult, SummaryRow

if TYPE_CHECKING:
    from plugins.calibration.kinematics import KinematicCalibration

_MM, _DEG = 1e3, float(np.degrees(1.0))
HAND_EYE_KINDS = ("hand_eye", "robot_world")


@dataclass
class Outcome:
    """What a calibration produced for the CLI: the result, notes about the input, extra report text,
    extra Markdown sections and a writer of extra report files."""

    result: CalibrationResult
    notes: list[str] = field(default_factory=list)
    extra_text: str = ""
    sections: dict[str, str] = field(default_factory=dict)
    write_files: Callable[[Path], None] | None = None


def _metric_text(name: str, value: float) -> tuple[str, str]:
    """(display name, value with unit): SI metric names ending in _m / _rad become mm / deg; _mm, _deg
    and _px keep their unit."""
    if name.endswith("_m"):
        return name[:-2] + "_mm", f"{value * _MM:.4g} mm"
    if name.endswith("_rad"):
        return name[:-4] + "_deg", f"{value * _DEG:.4g} deg"
    if name.endswith("_mm"):
        return name, f"{value:.4g} mm"
    if name.endswith("_deg"):
        return name, f"{value:.4g} deg"
    if name.endswith("_px"):
        return name, f"{value:.4g} px"
    return name, f"{value:.6g}"


def summary_table(rows: list[SummaryRow]) -> list[str]:
    """Plain-text table of summary rows."""
    width = max((len(r.name) for r in rows), default=10)
    lines = [f"  {'parameter':<{width}}  {'value':>12}  {'1 sigma':>10}  unit"]
    for r in rows:
        sig = "" if r.sigma is None else f"{r.sigma:.4f}"
        lines.append(f"  {r.name:<{width}}  {r.value:>12.4f}  {sig:>10}  {r.unit}")
    return lines


def residual_lines(result: CalibrationResult, max_rows: int = 60) -> list[str]:
    """Per-sample residuals: 3-D position error (the first three columns, mm) and rotation error
    (the next three, deg, when present), with outlier flags. Hand-eye has its own table."""
    if result.residuals is None or np.asarray(result.residuals).ndim != 2:
        return []
    R = np.asarray(result.residuals, dtype=float)
    if R.shape[1] < 3:
        return []
    pos = np.linalg.norm(R[:, :3], axis=1) * _MM
    rot = np.linalg.norm(R[:, 3:6], axis=1) * _DEG if R.shape[1] >= 6 else None
    out = np.zeros(len(R), bool) if result.outliers is None else np.asarray(result.outliers, dtype=bool)
    labels = result.estimate.get("sample_labels")
    labels = labels if isinstance(labels, list) and len(labels) == len(R) else [str(k) for k in range(len(R))]
    head = f"  {'sample':>8} {'position_mm':>12}" + (f" {'rotation_deg':>13}" if rot is not None else "")
    lines = [head]
    for k in range(min(len(R), max_rows)):
        row = f"  {labels[k]:>8} {pos[k]:12.4f}" + (f" {rot[k]:13.4f}" if rot is not None else "")
        lines.append(row + ("  OUTLIER" if out[k] else ""))
    if len(R) > max_rows:
        lines.append(f"  ... {len(R) - max_rows} more (all in result.json)")
    lines.append(
        f"  RMS {np.sqrt(np.mean(pos**2)):.4f} mm, max {pos.max():.4f} mm"
        + (f"; rotation RMS {np.sqrt(np.mean(rot**2)):.4f} deg" if rot is not None else "")
        + f"; {int(out.sum())} outlier(s)"
    )
    return lines


def format_result(result: CalibrationResult, *, per_sample: bool = True) -> str:
    """Plain-text report of any calibration result (mm, degrees), ending with reasons and advice."""
    if result.kind in HAND_EYE_KINDS:
        return format_hand_eye_report(result, per_sample=per_sample)
    lines = [
        f"{result.kind.replace('_', '-')} calibration: verdict {result.verdict.upper()}"
        + ("" if result.usable else " (NOT usable: do not use it to move a robot)"),
        f"method: {result.method}" + (f" ({result.iterations} iterations)" if result.iterations else ""),
        "estimate:",
        *summary_table(result.summary_rows()),
    ]
    if result.metrics:
        lines.append("metrics:")
        for name in sorted(result.metrics):
            shown, text = _metric_text(name, float(result.metrics[name]))
            lines.append(f"  {shown} = {text}")
    if per_sample:
        res = residual_lines(result)
        if res:
            lines.append("per-sample residuals:")
            lines += res
    return "\n".join(lines + result.reason_lines())


def summary_markdown(result: CalibrationResult, extra_sections: Mapping[str, str] | None = None) -> str:
    """Markdown summary: verdict, estimate table (mm, deg, 1-sigma), metrics, reasons, advice."""
    md = [
        f"# {result.kind.replace('_', '-')} calibration",
        "",
        f"**Verdict: {result.verdict}**" + ("" if result.usable else " (not usable)"),
        "",
        f"Method: {result.method}",
        "",
        "| parameter | value | 1 sigma | unit |",
        "|---|---:|---:|---|",
    ]
    for r in result.summary_rows():
        md.append(f"| {r.name} | {r.value:.4f} | {'' if r.sigma is None else f'{r.sigma:.4f}'} | {r.unit} |")
    if result.metrics:
        md += ["", "| metric | value |", "|---|---:|"]
        for name in sorted(result.metrics):
            shown, text = _metric_text(name, float(result.metrics[name]))
            md.append(f"| {shown} | {text} |")
    for title, items in (("Reasons", result.reasons), ("Advice", result.advice)):
        if items:
            md += ["", f"## {title}", ""] + [f"- {x}" for x in items]
    for title, body in (extra_sections or {}).items():
        md += ["", f"## {title}", "", body]
    return "\n".join(md) + "\n"


def write_report_dir(
    directory: str | Path,
    result: CalibrationResult,
    text: str,
    extra_sections: Mapping[str, str] | None = None,
) -> Path:
    """Write result.json, report.txt and summary.md into *directory* (created); returns it. Each file
    is replaced atomically (never left half-written)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    replace_text(d / "result.json", result.to_json(indent=1) + "\n")
    replace_text(d / "report.txt", text + "\n")
    replace_text(d / "summary.md", summary_markdown(result, extra_sections))
    return d


def kinematic_table(cal: KinematicCalibration) -> tuple[str, dict[str, str]]:
    """The before/after table of a kinematic calibration: text for the report and a Markdown section."""
    from plugins.calibration.kinematics import format_table

    table = format_table(cal)
    text = "before / after calibration (position errors in mm):\n" + table
    return text, {"Before / after (mm)": f"```\n{table}\n```"}


def write_kinematic_files(cal: KinematicCalibration, directory: str | Path) -> None:
    """convergence.png and before_after.txt of a kinematic calibration into *directory*."""
    from plugins.calibration.kinematics import format_table, plot_convergence

    d = Path(directory)
    plot_convergence(cal, d / "convergence.png")
    (d / "before_after.txt").write_text(format_table(cal) + "\n")
