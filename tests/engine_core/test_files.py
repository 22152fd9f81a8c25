"""engine.files: a file is replaced whole or not at all."""

from __future__ import annotations

import os

import pytest

from engine.files import replace_text, replacing


def test_a_failed_write_leaves_the_old_file_and_nothing_beside_it(tmp_path):
    path = tmp_path / "recipe.yaml"
    path.write_text("old")
    os.chmod(path, 0o640)
    with pytest.raises(OSError, match="disk full"), replacing(path) as tmp:
        tmp.write_text("half of the new")
        raise OSError("disk full")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["recipe.yaml"]
    replace_text(path, "new")
    assert path.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["recipe.yaml"]
    assert path.stat().st_mode & 0o777 == 0o640  # the mode of the file it replaced
