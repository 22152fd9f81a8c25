"""Docs name what a reader can look up: every file the README, docs/ and the code's docstrings cite exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# a path in the repository (docs/x.md, plugins/.../y.py, recipes/z.yaml, ...) or a top-level NAME.md
CITED = re.compile(
    r"(?<![\w/.-])((?:docs|engine|plugins|recipes|tests|benchmarks|recordings)/[\w./*-]+"
    r"\.(?:md|py|yaml|json|mcap|vgrtpl|png))|(?<![\w/.-])([A-Z][A-Z_]+\.md)"
)


def _texts() -> list[Path]:
    code = [p for d in ("engine", "plugins", "benchmarks") for p in sorted((ROOT / d).rglob("*.py"))]
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *code]


def cited_files(text: str) -> list[tuple[int, str]]:
    out = []
    for i, line in enumerate(text.splitlines(), 1):
        out += [(i, m.group(1) or m.group(2)) for m in CITED.finditer(line)]
    return out


def test_the_pattern_finds_what_it_should():
    assert cited_files("see docs/design.md and (SIM_API.md), not xdocs/a.md") == [
        (1, "docs/design.md"),
        (1, "SIM_API.md"),
    ]


@pytest.mark.parametrize("path", _texts(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_file_exists(path):
    missing = [
        f"{path.relative_to(ROOT)}:{line}: {ref}"
        for line, ref in cited_files(path.read_text(encoding="utf-8"))
        if not any(ROOT.glob(ref))
    ]
    assert not missing, "cited but not in the repository:\n" + "\n".join(missing)
