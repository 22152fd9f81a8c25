"""What a recipe's ``plugins:`` may name (engine.recipe.plugin_entries): an installed vgr plugin, a
plugin file by its path, or by its name next to the recipe or in ``VGR_PLUGIN_PATH``; never just any
importable module (``plugins: [this]`` ran the Zen of Python's import), never a file another user
may change."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from engine.errors import RecipeError
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe

PLUGIN = """
from typing import ClassVar

from engine.hookspecs import hookimpl
from engine.messages import Request
from engine.stage import Stage


class Quiet(Stage):
    type_name = "{type_name}"
    outputs: ClassVar = {{"out": Request}}


@hookimpl
def vgr_stage_types():
    return [Quiet]
"""


def recipe(folder: Path, plugins: str, type_name: str = "t_quiet") -> Path:
    path = folder / "cell.yaml"
    path.write_text(f"name: cell\nplugins: {plugins}\nstages:\n  q: {{type: {type_name}}}\n")
    return path


def plugin_file(path: Path, type_name: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(PLUGIN.format(type_name=type_name))
    return path


def test_an_installed_module_that_is_no_vgr_plugin_is_refused_before_it_is_imported(tmp_path):
    sys.modules.pop("this", None)
    with pytest.raises(RecipeError) as err:
        load_recipe(recipe(tmp_path, "[this]"))
    assert "'this' is neither an installed vgr plugin" in str(err.value) and "cell.yaml:2" in str(err.value)
    assert "this" not in sys.modules  # nothing was imported
    assert load_recipe(recipe(tmp_path, "[builtin]")).recipe.plugins == ["builtin"]  # an entry point


def test_a_plugin_file_is_named_by_its_path_or_its_name_next_to_the_recipe(tmp_path):
    plugin_file(tmp_path / "lib" / "cell_stages_a.py", "t_quiet_a")
    by_path = load_recipe(recipe(tmp_path, "[lib/cell_stages_a.py]", "t_quiet_a"))
    assert by_path.recipe.plugins == [str(tmp_path / "lib" / "cell_stages_a.py")]
    assert "t_quiet_a" in load_registry(by_path.recipe.plugins).stages
    plugin_file(tmp_path / "cell_stages_b.py", "t_quiet_b")
    by_name = load_recipe(recipe(tmp_path, "[cell_stages_b]", "t_quiet_b"))
    assert by_name.recipe.plugins == [str(tmp_path / "cell_stages_b.py")]
    with pytest.raises(RecipeError, match="does not exist"):
        load_recipe(recipe(tmp_path, "[lib/missing.py]"))


def test_plugin_folders_the_user_names_in_vgr_plugin_path(tmp_path, monkeypatch):
    plugin_file(tmp_path / "site" / "cell_stages_c.py", "t_quiet_c")
    (tmp_path / "cell").mkdir()
    with pytest.raises(RecipeError):
        load_recipe(recipe(tmp_path / "cell", "[cell_stages_c]", "t_quiet_c"))
    monkeypatch.setenv("VGR_PLUGIN_PATH", f"{tmp_path / 'nowhere'}:{tmp_path / 'site'}")
    loaded = load_recipe(recipe(tmp_path / "cell", "[cell_stages_c]", "t_quiet_c"))
    assert loaded.recipe.plugins == [str(tmp_path / "site" / "cell_stages_c.py")]


def test_a_plugin_file_others_may_change_is_refused(tmp_path):
    plugin = plugin_file(tmp_path / "cell_stages_d.py", "t_quiet_d")
    plugin.chmod(0o666)
    with pytest.raises(RecipeError, match="can be written by its group or by others"):
        load_recipe(recipe(tmp_path, "[cell_stages_d]", "t_quiet_d"))
    plugin.chmod(0o644)
    tmp_path.chmod(0o777)  # a folder others may write: they could put another file in its place
    try:
        with pytest.raises(RecipeError, match="can be written by its group or by others"):
            load_recipe(recipe(tmp_path, "[cell_stages_d]", "t_quiet_d"))
    finally:
        tmp_path.chmod(0o755)
