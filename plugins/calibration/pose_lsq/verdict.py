"""Findings of a calibration's checks and how they combine into the CalibrationResult verdict.

Each check yields :class:`Issue` objects; the verdict is the worst level found
(``failed`` > ``degenerate`` > ``warning`` > ``ok``; ``info`` never lowers it).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

from plugins.calibration.result import Verdict

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
