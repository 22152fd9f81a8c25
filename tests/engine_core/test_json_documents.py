"""``--json`` prints one versioned document per outcome, valid against its shipped JSON Schema
(engine/cli/schemas), also on invalid input; a run's document holds its results as typed fields and
every file its stages wrote."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest

from engine.cli.json_output import schema
from engine.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


def printed(capsys) -> dict:
    out = capsys.readouterr().out
    return json.loads(out)  # strict: the whole of stdout is one document


def test_a_run_document_holds_results_files_and_validates(tmp_path, capsys):
    code = main(["run", str(ROOT / "recipes/eye_in_hand_dock.yaml"), "--json", "--no-progress",
                 "--runs-dir", str(tmp_path), "--no-record"])  # fmt: skip
    doc = printed(capsys)
    jsonschema.validate(doc, schema("run"))
    assert doc["exit_code"] == code == 0 and doc["format"] == "vgr.run/1"
    (evaluation,) = [r for r in doc["results"] if r["code"] == "docking_evaluation"]
    assert isinstance(evaluation["details"], dict) and evaluation["details"]
    assert doc["files"], doc["results"]
    assert all(Path(f["path"]).is_file() for f in doc["files"])


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "recipes/eye_in_hand_dock.yaml", "-p", "matcher.nope=1"],
        ["validate", "recipes/eye_in_hand_dock.yaml", "-p", "matcher.nope=1"],
        ["run", "recipes/no_such_recipe.yaml"],
    ],
)
def test_invalid_input_prints_the_invalid_document(argv, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main([*argv, "--json"]) == 2
    doc = printed(capsys)
    jsonschema.validate(doc, schema("invalid"))
    assert doc["verb"] == argv[0] and doc["error"]


def test_a_valid_recipe_prints_the_validate_document(capsys):
    assert main(["validate", str(ROOT / "recipes/eye_in_hand_dock.yaml"), "--json"]) == 0
    jsonschema.validate(printed(capsys), schema("validate"))


def test_a_bad_command_line_value_is_reported_at_the_command_line_not_the_recipe(capsys):
    recipe = str(ROOT / "recipes/eye_in_hand_dock.yaml")
    assert main(["validate", recipe, "-p", "matcher.min_fitness=abc", "--json"]) == 2
    (problem,) = printed(capsys)["problems"]
    assert problem["file"] == "<command line> -p matcher.min_fitness=abc" and problem["line"] is None
    assert problem["key"] == "stages.matcher.params.min_fitness"
    assert main(["validate", recipe, "-p", "matcher.nope=1", "--json"]) == 2  # an unknown key too
    (problem,) = printed(capsys)["problems"]
    assert problem["file"].startswith("<command line>") and "nope" in problem["message"]


def test_a_replay_document_validates_and_is_the_replay_folders_file(tmp_path, capsys):
    code = main(["replay", str(ROOT / "recordings/demo.mcap"), "--json", "--runs-dir", str(tmp_path)])
    doc = printed(capsys)
    jsonschema.validate(doc, schema("replay"))
    assert doc["exit_code"] == code == 0 and doc["outcome"] == "ok"
    assert json.loads((Path(doc["run_folder"]) / "replay.json").read_text()) == doc
