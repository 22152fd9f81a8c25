"""Every command of examples/README.md runs as written on the shipped sample files."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from engine.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = re.findall(r"^\| `vgr ([^`]+)` \|", (ROOT / "examples" / "README.md").read_text(), flags=re.M)


def test_the_readme_lists_a_command_per_sample_file():
    assert len(COMMANDS) == 5
    files = {p.name for p in (ROOT / "examples").iterdir() if p.suffix in (".json", ".csv")}
    assert files == {Path(a).name for c in COMMANDS for a in shlex.split(c) if a.startswith("examples/")}


@pytest.mark.parametrize("command", COMMANDS)
def test_each_command_runs_as_written_with_a_usable_result(command, monkeypatch, capsys):
    """Usable: exit 0, or 3 for a calibration usable with a warning (engine/exit_codes.py)."""
    monkeypatch.chdir(ROOT)
    code = main(shlex.split(command))
    out = capsys.readouterr().out
    assert code == 0 or (code == 3 and "verdict WARNING" in out), out[-2000:]


def test_gap_names_the_hidden_compliance_within_its_sigma(monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    argv = ["gap", "--model", "ur5e", "--data", "examples/ur5e_campaign.csv", "--noise-mm", "0.05", "--json"]
    assert main(argv) == 0
    (e,) = json.loads(capsys.readouterr().out)["effects_added"]
    assert (e["name"], e["where"]) == ("joint_compliance", "joint2")
    est, sd = e["params"]["compliance_joint2"], e["param_std"]["compliance_joint2"]
    assert abs(est - 5.9195e-6) < 3 * sd, (est, sd)
