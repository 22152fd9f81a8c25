"""A stage parameter naming a file to write (``cloud_stats.output``, ``docking_evaluator.output``)
follows the run-folder rules: a relative name lands inside the run folder, an absolute one must be a
new file, never one the run did not create, never through a link."""

from __future__ import annotations

import json
from pathlib import Path

from engine.cli.main import main
from engine.exit_codes import ExitCode

ROOT = Path(__file__).resolve().parents[2]
DEMO = ["run", str(ROOT / "recipes/demo.yaml"), "--no-progress", "-p", "source.frames=2", "-p", "source.n_points=50"]


def run_demo(tmp_path: Path, output: str, capsys) -> tuple[int, dict]:  # type: ignore[no-untyped-def]
    code = main([*DEMO, "-p", f"stats.output={output}", "--runs-dir", str(tmp_path / "runs"), "--json"])
    return code, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_a_relative_output_lands_in_the_run_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, doc = run_demo(tmp_path, "stats/clouds.jsonl", capsys)
    assert code == ExitCode.OK
    written = list((tmp_path / "runs").glob("*/stats/clouds.jsonl"))
    assert len(written) == 1 and len(written[0].read_text().splitlines()) == 2
    assert "stats/clouds.jsonl" in json.dumps(doc["files"])  # named relative to the run folder
    assert not (tmp_path / "stats").exists()


def test_an_existing_file_or_a_link_is_never_written_over(tmp_path, capsys):
    mine = tmp_path / "mine.txt"
    mine.write_text("not vgr's")
    code, _ = run_demo(tmp_path, str(mine), capsys)
    assert code != ExitCode.OK and mine.read_text() == "not vgr's"
    link = tmp_path / "link.jsonl"
    link.symlink_to(tmp_path / "elsewhere.jsonl")  # (a dangling link: root would create its target)
    code, _ = run_demo(tmp_path, str(link), capsys)
    assert code != ExitCode.OK and not (tmp_path / "elsewhere.jsonl").exists()
    code, _ = run_demo(tmp_path, str(tmp_path / "new" / "clouds.jsonl"), capsys)
    assert code == ExitCode.OK and (tmp_path / "new" / "clouds.jsonl").is_file()
