"""The README's table of jobs runs as written: each `vgr run` / `vgr gap` command of "What you can
run" exits 0 on the simulated cell (from a copy of recipes/ and examples/, so nothing lands in the
repository)."""

from __future__ import annotations

import glob
import re
import shlex
import shutil
from pathlib import Path

import pytest

from engine.cli.main import main

pytestmark = pytest.mark.timeout(600)

ROOT = Path(__file__).resolve().parents[1]


def table_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    table = text.split("## What you can run", 1)[1].split("\n## ", 1)[0]
    cmds = re.findall(r"`(vgr (?:run|gap) [^`]+)`", table)
    out = []
    for cmd in cmds:  # a glob in a recipe path stands for every recipe it matches
        argv = shlex.split(cmd)
        patterns = [a for a in argv if "*" in a]
        if not patterns:
            out.append(cmd)
            continue
        (pattern,) = patterns
        for match in sorted(glob.glob(str(ROOT / pattern))):
            out.append(cmd.replace(pattern, str(Path(match).relative_to(ROOT))))
    return out


COMMANDS = table_commands()


def test_the_table_names_every_shipped_job():
    ran = {Path(a).name for c in COMMANDS for a in shlex.split(c) if a.startswith("recipes/")}
    assert {"eye_in_hand_dock.yaml", "planar_assembly.yaml", "model_gap_sim.yaml"} <= ran
    assert {f"calibrate_{k}_sim.yaml" for k in ("handeye", "tcp", "vive_desk", "kinematics")} <= ran
    assert any(c.startswith("vgr gap ") for c in COMMANDS)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "recipes", d / "recipes")
    shutil.copytree(ROOT / "examples", d / "examples")
    return d


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS)
def test_each_job_runs_as_written(command, workdir, monkeypatch, capsys):
    monkeypatch.chdir(workdir)
    rc = main(shlex.split(command)[1:])  # (no progress display: the test's output is not a terminal)
    assert rc == 0, capsys.readouterr().out[-3000:]
