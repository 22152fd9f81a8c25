"""``--report DIR`` of ``vgr calibrate`` and ``vgr gap``: a new or empty folder, never one that holds an
earlier report (it was overwritten silently), never a link; refused before any work (exit 2)."""

from __future__ import annotations

import pytest

from engine.cli.main import main
from engine.run_folder import OutputDirError, new_folder


@pytest.mark.parametrize(
    "argv",
    [
        ["calibrate", "kinematics", "examples/ur5e_campaign.csv", "--model", "ur5e"],
        ["gap", "--model", "ur5e", "--data", "examples/ur5e_campaign.csv"],
    ],
)
def test_a_report_folder_holding_an_earlier_report_is_refused_and_kept(argv, tmp_path, capsys):
    earlier = tmp_path / "report"
    earlier.mkdir()
    (earlier / "result.json").write_text('{"earlier": true}')
    assert main([*argv, "--report", str(earlier)]) == 2
    assert "holds files" in capsys.readouterr().err
    assert [p.name for p in earlier.iterdir()] == ["result.json"]
    assert (earlier / "result.json").read_text() == '{"earlier": true}'


def test_new_and_empty_folders_are_taken_links_and_files_are_not(tmp_path):
    assert new_folder(tmp_path / "a" / "b", "--report").is_dir()
    (tmp_path / "empty").mkdir()
    assert new_folder(tmp_path / "empty", "--report") == tmp_path / "empty"
    (tmp_path / "link").symlink_to(tmp_path / "empty")
    with pytest.raises(OutputDirError, match="is a link"):
        new_folder(tmp_path / "link", "--report")
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputDirError, match="is a file"):
        new_folder(tmp_path / "f", "--report")
