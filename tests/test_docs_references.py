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


# a folder in the repository, written with its trailing slash (plugins/calibration/)
CITED_DIR = re.compile(
    r"(?<![\w/.-])((?:docs|engine|plugins|recipes|tests|benchmarks|recordings|examples)/(?:[\w-]+/)*)(?![\w.-])"
)
# a Markdown link [text](target), target not a URL
MD_LINK = re.compile(r"\[[^\]]*\]\((?!https?:|mailto:)([^)\s]+)\)")


def heading_anchors(markdown: str) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation but '-' and '_' dropped,
    spaces to '-' (a repeated heading gets '-1', '-2', ...)."""
    seen: dict[str, int] = {}
    out = set()
    for line in markdown.splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_the_folder_and_link_patterns_find_what_they_should():
    assert CITED_DIR.findall("see plugins/calibration/ and (docs/), not xplugins/a/ or docs/a.md") == [
        "plugins/calibration/",
        "docs/",
    ]
    assert MD_LINK.findall("[a](docs/x.md#y) [b](https://e.org) [c](z.md)") == ["docs/x.md#y", "z.md"]


def test_heading_anchors_follow_github():
    text = "# Watching a run live in Foxglove\n## Exit codes: one table\n## Exit codes: one table\n"
    assert heading_anchors(text) == {
        "watching-a-run-live-in-foxglove",
        "exit-codes-one-table",
        "exit-codes-one-table-1",
    }


@pytest.mark.parametrize("path", _texts(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_folder_exists(path):
    text = path.read_text(encoding="utf-8")
    missing = [
        f"{path.relative_to(ROOT)}:{i}: {m.group(1)}"
        for i, line in enumerate(text.splitlines(), 1)
        for m in CITED_DIR.finditer(line)
        if not (ROOT / m.group(1)).is_dir()
    ]
    assert not missing, "folders cited but not in the repository:\n" + "\n".join(missing)


@pytest.mark.parametrize(
    "path", [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))], ids=lambda p: str(p.relative_to(ROOT))
)
def test_every_markdown_link_reaches_its_file_and_heading(path):
    broken = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        for m in MD_LINK.finditer(line):
            target, _, anchor = m.group(1).partition("#")
            dest = (path.parent / target).resolve() if target else path
            if not dest.exists():
                broken.append(f"{path.relative_to(ROOT)}:{i}: {m.group(1)} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in heading_anchors(dest.read_text(encoding="utf-8")):
                broken.append(f"{path.relative_to(ROOT)}:{i}: {m.group(1)} (no such heading)")
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_every_page_in_docs_is_linked_from_the_readme_or_another_page():
    pages = sorted((ROOT / "docs").glob("*.md"))
    linked: set[Path] = set()
    for md in [ROOT / "README.md", *pages]:
        for target in MD_LINK.findall(md.read_text()):
            linked.add((md.parent / target.split("#", 1)[0]).resolve())
    orphans = [p.name for p in pages if p.resolve() not in linked]
    assert not orphans, f"pages no reader can find from the README: {orphans}"


@pytest.mark.parametrize("path", [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))], ids=lambda p: p.name)
def test_docs_cite_what_a_reader_can_look_up_not_the_issue_tracker(path):
    text = " ".join(path.read_text().split())
    assert not re.search(r"\bthe issue(?:'s| tracker| asks)\b", text), path.name


def test_the_stage_example_uses_every_name_it_imports_and_defines_a_working_stage():
    import ast

    text = (ROOT / "docs" / "writing_stages.md").read_text()
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    tree = ast.parse(code)
    imported = {
        a.asname or a.name.split(".")[0]
        for n in ast.walk(tree)
        if isinstance(n, ast.Import | ast.ImportFrom)
        for a in n.names
    }
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} | {
        n.value.id for n in ast.walk(tree) if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
    }
    assert imported <= used, f"imported, never used: {sorted(imported - used)}"
    namespace: dict = {}
    exec(compile(code, "writing_stages.md", "exec"), namespace)
    (stage,) = namespace["vgr_stage_types"]()
    assert stage.type_name == "centroid" and stage.Params(min_points=3).min_points == 3
