"""`vgr run` tells a cell controller what the job came to: its exit code and --json `outcome`.

A refused dock must not look like a success to a PLC: an alarm (a stage refused its motion) exits 1,
a failed stage 4, an interrupted run 130, and only a clean run 0 (engine/exit_codes.py, README *Exit codes*).
"""

from __future__ import annotations

import json
import re

import pytest

from engine.cli.main import main
from engine.exit_codes import OUTCOME_EXIT_CODES
from engine.messages import Event
from engine.run.runner import RunSummary


def summary(ok: bool = True, stop_reason: str | None = None, levels: tuple[str, ...] = ()) -> RunSummary:
    events = [Event(level=lv, stage="s", code="c", message="m") for lv in levels]
    return RunSummary("r", "recipe", "main", ok, stop_reason, [], 0.1, events)


@pytest.mark.parametrize(
    ("kw", "outcome", "code"),
    [
        ({}, "ok", 0),
        ({"levels": ("info", "result", "warning")}, "ok", 0),  # a warning is not a refusal
        ({"levels": ("warning", "alarm")}, "refused", 1),
        ({"ok": False, "stop_reason": "stage 'x' failed", "levels": ("alarm", "error")}, "failed", 4),
        ({"ok": False, "stop_reason": "interrupted (Ctrl-C)", "levels": ("alarm",)}, "interrupted", 130),
    ],
)
def test_outcome_and_exit_code_of_a_summary(kw, outcome, code):
    s = summary(**kw)
    assert (s.outcome, s.exit_code) == (outcome, code)
    assert OUTCOME_EXIT_CODES[outcome] == code


def test_a_refused_dock_exits_1_and_says_refused_in_json(capsys):
    # guidance may move at most 1 mm per step: the first correction (~20 mm) is refused, nothing docks
    argv = ["run", "recipes/eye_in_hand_dock.yaml", "-p", "guidance.max_step_mm=1", "--no-progress", "--json"]
    assert main(argv) == 1
    out = json.loads(capsys.readouterr().out)
    assert (out["outcome"], out["exit_code"], out["ok"]) == ("refused", 1, False)
    alarms = {(e["stage"], e["code"]) for e in out["events"] if e["level"] == "alarm"}
    assert alarms == {("guidance", "correction_limit"), ("docking", "guidance_not_usable")}, alarms


def test_a_refused_run_says_so_in_its_last_line(capsys):
    assert main(["run", "recipes/eye_in_hand_dock.yaml", "-p", "guidance.max_step_mm=1", "--no-progress"]) == 1
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("run finished, refused") and "alarm" in last


def test_a_clean_run_exits_0_with_outcome_ok(capsys):
    assert main(["run", "recipes/demo.yaml", "-p", "source.frames=3", "--no-progress", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["outcome"], out["exit_code"], out["ok"]) == ("ok", 0, True)


def test_the_readme_table_is_the_exit_code_table():
    from pathlib import Path

    from engine.exit_codes import ExitCode

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("### Exit codes") :]
    section = section[: section.index("\n\n", section.index("| code |"))]
    assert {int(c) for c in re.findall(r"^\| (\d+) \|", section, re.M)} == {int(c) for c in ExitCode}


def test_only_engine_exit_codes_defines_exit_codes():
    """No module but engine/exit_codes.py binds an EXIT_* name to a number or returns a bare
    number from a verb: one table, one meaning per number (README, *Exit codes*)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    found = []
    for path in [*root.glob("engine/**/*.py"), *root.glob("plugins/**/*.py")]:
        if path.name == "exit_codes.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets = node.targets if isinstance(node, ast.Assign) else []
            names = [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
            numbers = [n for n in ast.walk(node.value) if isinstance(n, ast.Constant)] if targets else []
            if any(n.startswith("EXIT_") for n in names) and any(isinstance(c.value, int) for c in numbers):
                found.append(f"{path.relative_to(root)}:{node.lineno}")
            if ("cli" in path.parts or path.name.endswith("cli.py")) and (
                isinstance(node, ast.Return) and isinstance(node.value, ast.Constant) and type(node.value.value) is int
            ):
                found.append(f"{path.relative_to(root)}:{node.lineno}: return {node.value.value}")
    assert not found, found
