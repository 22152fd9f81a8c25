"""vgr never writes through a link it did not make: a replaced file goes through an unpredictable,
exclusively created temporary file; a new file (a recording) is created with O_EXCL | O_NOFOLLOW, so
a link planted at its name, dangling or not, is refused instead of followed."""

from __future__ import annotations

import pytest

from engine.cli.main import main
from engine.files import create_new, replace_text, replacing


def test_a_link_planted_where_the_old_temporary_name_was_is_not_written_through(tmp_path):
    victim = tmp_path / "root_only.txt"
    victim.write_text("precious")
    (tmp_path / ".out.json.partial").symlink_to(victim)  # the name the temporary file used to have
    replace_text(tmp_path / "out.json", "new")
    assert victim.read_text() == "precious" and (tmp_path / "out.json").read_text() == "new"


def test_replacing_a_link_replaces_the_link_not_the_file_it_points_to(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "out.json").symlink_to(victim)
    replace_text(tmp_path / "out.json", "new")
    assert victim.read_text() == "precious"
    assert not (tmp_path / "out.json").is_symlink() and (tmp_path / "out.json").read_text() == "new"


def test_a_failed_write_leaves_neither_half_a_file_nor_a_temporary_one(tmp_path):
    with pytest.raises(RuntimeError), replacing(tmp_path / "out.bin") as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("crash")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dangling", [True, False])
def test_a_new_file_is_never_created_through_a_link(tmp_path, dangling):
    target = tmp_path / "elsewhere.mcap"
    if not dangling:
        target.write_bytes(b"keep")
    (tmp_path / "run.mcap").symlink_to(target)
    with pytest.raises(FileExistsError):
        create_new(tmp_path / "run.mcap")
    assert target.exists() != dangling and (dangling or target.read_bytes() == b"keep")


def test_record_to_a_dangling_link_is_refused(tmp_path, capsys):
    target = tmp_path / "anywhere.mcap"
    (tmp_path / "run.mcap").symlink_to(target)
    code = main(["run", "recipes/demo.yaml", "--no-progress", "--record", str(tmp_path / "run.mcap"),
                 "--runs-dir", str(tmp_path / "runs")])  # fmt: skip
    assert code == 2 and not target.exists()
