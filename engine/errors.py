"""Errors a user sees before anything runs: each names the file, line, offending key and a fix.

A :class:`RecipeError` carries every :class:`Problem` found (not just the first), formatted as
``file:line:col: key.path: message (did you mean 'x'?)`` like a compiler.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class Problem:
    message: str
    key: str = ""
    file: str | None = None
    line: int | None = None  # 1-based
    column: int | None = None  # 1-based
    suggestion: str | None = None

    def __str__(self) -> str:
        where = self.file or "<recipe>"
        if self.line is not None:
            where += f":{self.line}"
            if self.column is not None:
                where += f":{self.column}"
        text = f"{where}: "
        if self.key:
            text += f"{self.key}: "
        text += self.message
        if self.suggestion:
            text += f" (did you mean {self.suggestion!r}?)"
        return text


class RecipeError(ValueError):
    """One or more problems in a recipe; ``problems`` lists them all in file order."""

    def __init__(self, problems: Iterable[Problem]) -> None:
        self.problems = sorted(problems, key=lambda p: (p.line or 0, p.column or 0, p.key))
        if not self.problems:
            self.problems = [Problem("invalid recipe")]
        super().__init__("\n".join(str(p) for p in self.problems))


def nearest(name: str, candidates: Iterable[str]) -> str | None:
    """The closest candidate to *name* (for 'did you mean'), or None when nothing is close."""
    matches = difflib.get_close_matches(str(name), sorted(set(candidates)), n=1, cutoff=0.6)
    return matches[0] if matches else None
