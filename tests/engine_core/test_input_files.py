"""Input files a recipe names (a template, a hand-eye result, a calibration file, frame folders) are
checked by ``vgr validate`` and ``vgr run`` before anything starts: a missing one is invalid input
(exit 2), said once at the recipe's line, with no traceback. Before, validate said ok and the run
failed in set-up (exit 1), repeating the message six times."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
DOCK = ROOT / "recipes/eye_in_hand_dock.yaml"


@pytest.mark.parametrize("verb", ["validate", "run"])
def test_a_missing_template_is_invalid_input_before_anything_runs(verb, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main([verb, str(DOCK), "-p", "matcher.template=templates/missing.vgrtpl", "--json"])
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == out["exit_code"] == 2
    text = captured.out + captured.err
    assert "Traceback" not in text
    (problem,) = [p for p in out["problems"] if "no such file or folder" in p["message"]]
    assert problem["key"] == "stages.matcher.params.template"
    assert str(ROOT / "recipes/templates/missing.vgrtpl") in problem["message"]
    assert not (tmp_path / "runs").exists()  # nothing was started, no run folder made


def test_relative_input_files_are_found_next_to_the_recipe_wherever_vgr_runs(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["validate", str(DOCK)]) == 0


def test_only_the_stages_of_the_process_run_here_are_checked(tmp_path, capsys):
    recipe = tmp_path / "r.yaml"
    recipe.write_text(
        "name: two\nprocesses: {vision: {}}\nstages:\n"
        "  cam: {type: file_camera, params: {folder: scans}}\n"
        "  start: {type: trigger, params: {count: 1}}\n"
        "  calib: {type: calibration_file, process: vision, params: {path: result.json}}\n"
    )
    assert main(["validate", str(recipe), "--process", "vision"]) == 2  # result.json is missing
    assert "calib.params.path" in capsys.readouterr().err
    (tmp_path / "result.json").write_text("{}")
    assert main(["validate", str(recipe), "--process", "vision"]) == 0  # scans/ belongs to main
    assert main(["validate", str(recipe)]) == 2


@pytest.mark.parametrize(
    "override", ["guidance.max_total_mm=.inf", "guidance.translation_tol_mm=.nan", "guidance.max_step_deg=-.inf"]
)
def test_an_infinite_or_nan_limit_is_refused_not_taken_as_no_limit(override, capsys):
    """`.inf` as max_total_mm switched the limit off (rc 0): a limit may be absent, never infinite."""
    assert main(["validate", str(DOCK), "-p", override, "--json"]) == 2
    (problem,) = json.loads(capsys.readouterr().out)["problems"]
    assert problem["key"] == "stages.guidance.params." + override.split("=")[0].split(".")[1]
