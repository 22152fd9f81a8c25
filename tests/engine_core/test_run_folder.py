"""One folder per run and per replay (engine/run_folder.py): everything a run writes is in it, and
nothing one run or replay wrote is replaced by another."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from engine import run_folder
from engine.cli.main import main

DOCK = "recipes/eye_in_hand_dock.yaml"


def digest(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def run_json(capsys, *argv: str) -> dict:
    code = main([*argv, "--no-progress", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["exit_code"] == code
    return out


def test_a_run_keeps_recording_recipe_log_and_reports_in_its_own_folder(tmp_path, capsys):
    out = run_json(capsys, "run", DOCK, "--runs-dir", str(tmp_path), "-p", "guidance.max_iterations=4")
    folder = Path(out["artifacts"]["run folder"])
    assert folder.parent == tmp_path and folder.name.endswith("-eye_in_hand_dock")
    assert Path(out["artifacts"]["recording"]) == folder / "eye_in_hand_dock.mcap"
    files = set(digest(folder))
    assert {"eye_in_hand_dock.mcap", "recipe.yaml", "run.log", "report/job1.json", "report/job1.png"} <= files
    recipe = (folder / "recipe.yaml").read_text()
    assert "overrides: guidance.max_iterations=4" in recipe and "max_iterations: 4" in recipe
    log = (folder / "run.log").read_text()
    assert "starting" in log and "ended: ok" in log and "[guidance_report]" in log
    # the result event names its files relative to the run folder (a replay names them alike)
    result = next(e for e in out["events"] if e["level"] == "result" and e["stage"] == "report")
    assert result["code"] == "guidance_report"


def test_a_second_run_and_a_replay_replace_nothing_the_first_run_wrote(tmp_path, capsys):
    first = Path(run_json(capsys, "run", DOCK, "--runs-dir", str(tmp_path))["artifacts"]["run folder"])
    before = digest(first)
    second = Path(run_json(capsys, "run", DOCK, "--runs-dir", str(tmp_path))["artifacts"]["run folder"])
    assert second != first and second.parent == tmp_path  # same second, same recipe: a new folder
    code = main(["replay", str(first / "eye_in_hand_dock.mcap"), "--runs-dir", str(tmp_path), "--json"])
    replayed = json.loads(capsys.readouterr().out)
    assert (code, replayed["outcome"], replayed["recorded_outcome"]) == (0, "ok", "ok")
    replay_dir = Path(replayed["run_folder"])
    assert replay_dir not in (first, second) and "replay-eye_in_hand_dock" in replay_dir.name
    assert {"replay.json", "recipe.yaml", "run.log", "report/job1.json"} <= set(digest(replay_dir))
    assert digest(first) == before


def test_replay_exit_code_tells_the_replayed_outcome(tmp_path, capsys):
    rec = tmp_path / "dock.mcap"
    assert main(["run", DOCK, "--record", str(rec), "--runs-dir", str(tmp_path), "--no-progress"]) == 0
    capsys.readouterr()
    # the same recording replayed with guidance limited to 1 mm per step: the dock is refused, so
    # its outputs differ from the recorded ones: the replay did not reproduce the run
    argv = ["replay", str(rec), "--runs-dir", str(tmp_path), "--json", "-p", "guidance.max_step_mm=1"]
    code = main(argv)
    out = json.loads(capsys.readouterr().out)
    assert (code, out["outcome"], out["exit_code"]) == (1, "different", 1)
    assert any("correction_limit" in a for a in out["alarms"])


def test_a_refused_recording_replays_refused_and_that_is_a_pass(tmp_path, capsys):
    rec = tmp_path / "refused.mcap"
    argv = ["run", DOCK, "-p", "guidance.max_step_mm=1", "--record", str(rec), "--runs-dir", str(tmp_path)]
    assert main([*argv, "--no-progress"]) == 1
    capsys.readouterr()
    assert main(["replay", str(rec), "--runs-dir", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["outcome"], out["exit_code"], out["recorded_outcome"]) == ("ok", 0, "refused")
    assert any("correction_limit" in a for a in out["alarms"])  # the refusal came back with the outputs


def test_a_replay_that_cannot_start_leaves_no_folder(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "missing.mcap"), "--runs-dir", str(tmp_path / "runs")]) == 2
    assert not list((tmp_path / "runs").glob("*"))


def test_a_stage_folder_named_by_the_user_must_be_new_or_empty(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    assert run_folder.output_dir(run_dir, "report", None) == run_dir / "report"
    assert run_folder.output_dir(run_dir, "report", "plots/a") == run_dir / "plots" / "a"  # relative: inside
    assert run_folder.output_dir(None, "report", None) is None  # no run folder, nothing named: no files
    mine = tmp_path / "mine"
    assert run_folder.output_dir(run_dir, "report", mine) == mine and mine.is_dir()  # new: made
    (mine / "keep.txt").write_text("the user's")
    with pytest.raises(run_folder.OutputDirError, match="exists and holds files"):
        run_folder.output_dir(run_dir, "report", mine)
    with pytest.raises(run_folder.OutputDirError, match="exists and holds files"):
        run_folder.output_dir(None, "report", mine)
    with pytest.raises(run_folder.OutputDirError, match="is a file"):
        run_folder.output_dir(run_dir, "report", mine / "keep.txt")
    assert (mine / "keep.txt").read_text() == "the user's"


def test_a_run_with_a_report_dir_that_holds_files_fails_and_keeps_them(tmp_path, capsys):
    mine = tmp_path / "reports"
    mine.mkdir()
    (mine / "job1.json").write_text("an earlier run's report")
    argv = ["run", DOCK, "-p", f"report.report_dir={mine}", "--runs-dir", str(tmp_path / "runs"), "--no-progress"]
    assert main(argv) == 4  # failed
    assert "exists and holds files" in capsys.readouterr().out
    assert (mine / "job1.json").read_text() == "an earlier run's report"


@given(st.text(max_size=40))
def test_a_run_id_is_one_safe_file_name_component(run_id):
    name = run_folder.safe_name(run_id)
    assert name and "/" not in name and name not in (".", "..") and "*" not in name and "\0" not in name


def test_folders_made_in_the_same_second_differ(tmp_path):
    made = {run_folder.create(tmp_path, "same") for _ in range(5)}
    assert len(made) == 5 and all(p.is_dir() for p in made)
