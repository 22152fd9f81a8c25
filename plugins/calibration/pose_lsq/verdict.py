"""Findings of a calibration's checks and how they combine into the CalibrationResult verdict.

Each check yields :class:`Issue` objects; the verdict is the worst level found
(``failed`` > ``degenerate`` > ``warning`` > ``ok``; ``info`` never lowers it).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

from plugins.calibration.result import CalibrationResult, Verdict

Level = Literal["info", "warning", "degenerate", "failed"]
_RANK = {"info": 0, "warning": 1, "degenerate": 2, "failed": 3}


@dataclass(frozen=True)
class Issue:
    level: Level
    message: str
    advice: str = ""


def combine_verdict(issues: Iterable[Issue]) -> tuple[Verdict, list[str], list[str]]:
    """(verdict, reasons, advice) from a list of issues; reasons keep the issue order."""
    worst = 0
    reasons: list[str] = []
    advice: list[str] = []
    for it in issues:
        worst = max(worst, _RANK[it.level])
        reasons.append(f"[{it.level}] {it.message}")
        if it.advice and it.advice not in advice:
            advice.append(it.advice)
    verdict: Verdict = ("ok", "warning", "degenerate", "failed")[worst]  # type: ignore[assignment]
    return verdict, reasons, advice


def result_from_issues(kind: str, issues: Iterable[Issue], **fields: Any) -> CalibrationResult:
    """The CalibrationResult of *kind* whose verdict, reasons and advice are *issues* combined;
    *fields* are the rest of it (estimate, covariance, residuals, metrics, method, ...)."""
    verdict, reasons, advice = combine_verdict(issues)
    return CalibrationResult(kind=kind, verdict=verdict, reasons=reasons, advice=advice, **fields)
