"""A private socket folder that others may open (or another user owns) is refused with a clear
message and exit 2, before anything runs, not with a traceback."""

from __future__ import annotations

from pathlib import Path

from engine.cli.main import main
from engine.exit_codes import ExitCode

ROOT = Path(__file__).resolve().parents[2]


def test_an_open_socket_folder_is_refused_with_exit_2(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "vgr"
    folder.mkdir()
    folder.chmod(0o777)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    code = main(
        ["run", str(ROOT / "recipes/demo.yaml"), "--listen", "private", "--no-progress", "--runs-dir", str(tmp_path)]
    )
    assert code == ExitCode.INVALID
    said = capsys.readouterr()
    assert "mode 0700" in said.out + said.err and "Traceback" not in said.out + said.err
