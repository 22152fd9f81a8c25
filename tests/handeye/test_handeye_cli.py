"""The command-line front end: report on stdout, result JSON, exit codes."""

import json
from pathlib import Path

from shared_data import SHARED

from plugins.solvers.handeye.cli import main

DATA = str(SHARED / "moveit_calibration" / "pose_samples.json")


def test_cli_reports_and_writes_the_result(tmp_path: Path, capsys):
    out = tmp_path / "result.json"
    assert main([DATA, "--setup", "eye_to_hand", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "T_base_cam" in text and "pose-chain spread" in text
    assert json.loads(out.read_text())["estimate"]["setup"] == "eye_to_hand"


def test_cli_exit_codes_for_refused_and_bad_input(capsys):
    assert main([DATA, "--setup", "eye_in_hand"]) == 1  # wrong set-up: failed verdict
    assert main([DATA, "--setup", "eye_to_hand", "--mm"]) == 2  # metres read as millimetres
    assert "bad input" in capsys.readouterr().err
