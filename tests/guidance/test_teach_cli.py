"""`vgr teach photo|install`: the robot's pose goes into the recipe, in place, comments kept."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.cli.main import main
from engine.recipe.model import load_recipe
from plugins.actions.teach_cli import pose_text
from plugins.robot.model_file import load_robot_model
from plugins.vendor_poses import T_from_ur

RECIPES = Path(__file__).resolve().parents[2] / "recipes"


@pytest.fixture
def recipe(tmp_path: Path) -> Path:
    shutil.copytree(RECIPES / "templates", tmp_path / "templates")
    dst = tmp_path / "eye_in_hand_dock.yaml"
    shutil.copy(RECIPES / "eye_in_hand_dock.yaml", dst)
    return dst


def vars_of(path: Path) -> dict:
    return load_recipe(str(path)).recipe.model_dump()["vars"]


def test_photo_pose_comes_from_the_robot_state(recipe: Path) -> None:
    before = recipe.read_text()
    assert main(["teach", "photo", str(recipe)]) == 0
    after = recipe.read_text()
    T = np.array(vars_of(recipe)["photo_pose"]["matrix"])
    ur5e = load_robot_model("ur5e")  # the recipe's simulated robot starts at the model's home joints
    assert np.allclose(T, ur5e.fk(ur5e.home), atol=1e-6)
    changed = [(a, b) for a, b in zip(before.splitlines(), after.splitlines(), strict=True) if a != b]
    assert len(changed) == 1 and "photo_pose" in changed[0][0]  # one line, comments untouched


def test_install_pose_from_a_pendant_reading(recipe: Path) -> None:
    ur = [0.4, 0.1, 0.3, 3.0, 0.2, -0.1]
    assert main(["teach", "install", str(recipe), "--pose", ",".join(map(str, ur))]) == 0
    T = np.array(vars_of(recipe)["install_pose"]["matrix"])
    assert np.allclose(T, T_from_ur(ur), atol=2e-6)


def test_negative_values_after_the_option_are_the_pose_not_options(recipe: Path) -> None:
    ur = [-0.47, -0.07, 0.15, -3.0, 0.2, -0.1]  # typed as a pendant shows it: "--pose -0.47,..."
    assert main(["teach", "install", str(recipe), "--pose", ",".join(map(str, ur))]) == 0
    T = np.array(vars_of(recipe)["install_pose"]["matrix"])
    assert np.allclose(T, T_from_ur(ur), atol=2e-6)


def test_a_pose_beyond_the_robots_reach_is_refused_and_the_recipe_kept(recipe: Path, capsys) -> None:
    text = recipe.read_text()
    # the pendant's millimetres typed where metres are expected: 470 m from the base
    assert main(["teach", "install", str(recipe), "--pose", "-470,-70,150,0,3.14,0"]) == 2
    said = capsys.readouterr().out
    assert "cannot teach" in said and "beyond the ur5e's reach" in said and "millimetres" in said
    assert recipe.read_text() == text
    assert main(["teach", "install", str(recipe), "--pose", "1.2,0.6,0.3,0,3.14,0"]) == 2  # 1.38 m: too far
    assert recipe.read_text() == text


def test_reach_checks_an_adapters_workspace_box_and_any_robots_reach() -> None:
    from types import SimpleNamespace

    from plugins.actions.teach_cli import reach_problem

    ur = SimpleNamespace(params={"workspace_min_m": [-0.8, -0.6, 0.05], "workspace_max_m": [0.2, 0.6, 0.8]})
    assert reach_problem("robot", ur, T_from_ur([-0.47, -0.07, 0.15, 0, 3.14, 0])) is None
    assert "outside robot's workspace box" in reach_problem("robot", ur, T_from_ur([-0.47, -0.07, 0.01, 0, 3.14, 0]))
    unknown = SimpleNamespace(params={})
    assert reach_problem("arm", unknown, T_from_ur([2.5, 0, 1, 0, 0, 0])) is None  # a large robot may
    assert "beyond any robot's reach" in reach_problem("arm", unknown, T_from_ur([-470, -70, 150, 0, 0, 0]))


def test_stage_parameter_when_there_is_no_variable(tmp_path: Path) -> None:
    text = (
        (RECIPES / "eye_to_hand_dock.yaml")
        .read_text()
        .replace('photo_pose: "${photo_pose}"', "photo_pose: {xyz_m: [0, 0, 0.5]}")
    )
    path = tmp_path / "r.yaml"
    path.write_text(text.replace("  photo_pose: {matrix:", "  unused_photo: {matrix:"))
    shutil.copytree(RECIPES / "templates", tmp_path / "templates")
    assert main(["teach", "photo", str(path), "--pose", "0.1,0.2,0.3,0,0,0"]) == 0
    params = load_recipe(str(path)).recipe.stages["guidance"].params
    assert np.allclose(np.array(params["photo_pose"]["matrix"])[:3, 3], [0.1, 0.2, 0.3])


@pytest.mark.parametrize(
    "argv",
    [
        ["teach", "photo", "no/such/recipe.yaml"],
        ["teach", "photo", "DEMO", "--pose", "0,0,0,0,0,0"],
        ["teach", "install", "RECIPE", "--pose", "1,2,3"],
        ["teach", "install", "RECIPE", "--pose", "1,2,3,nan,0,0"],
        ["teach", "photo", "RECIPE", "--robot", "camera"],
        ["teach", "photo", "RECIPE", "--robot", "nobody"],
    ],
)
def test_bad_input_is_refused_and_the_recipe_is_left_alone(recipe: Path, argv: list[str]) -> None:
    demo = recipe.with_name("demo.yaml")  # a recipe with no photo pose to teach (a copy: it must stay as is)
    shutil.copy(RECIPES / "demo.yaml", demo)
    argv = [{"RECIPE": str(recipe), "DEMO": str(demo)}.get(a, a) for a in argv]
    before = {p: p.read_text() for p in (recipe, demo)}
    assert main(argv) == 2
    assert {p: p.read_text() for p in (recipe, demo)} == before


def test_a_taught_pose_that_breaks_the_recipe_leaves_the_file_as_it_was(tmp_path: Path, capsys) -> None:
    """vars.photo_pose is also used where a number belongs: the taught matrix would make the recipe
    invalid, so teach refuses and the file keeps every byte (it is validated before it is written)."""
    text = (RECIPES / "demo.yaml").read_text()
    text = text.replace("  n_points: 5000\n", "  n_points: 5000\n  photo_pose: 30\n")
    text = text.replace("frames: 30,", 'frames: "${photo_pose}",')
    path = tmp_path / "r.yaml"
    path.write_text(text)
    load_recipe(str(path))  # valid as written
    assert main(["teach", "photo", str(path), "--pose", "0.1,0.2,0.3,0,0,0"]) == 2
    assert "cannot teach" in capsys.readouterr().out
    assert path.read_text() == text


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-2, 2), min_size=3, max_size=3),
    st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
)
def test_written_pose_text_is_a_valid_rigid_transform_within_a_micrometre(t: list[float], r: list[float]) -> None:
    import yaml

    from engine.transforms import as_transform, pose_error

    T = T_from_ur([*t, *r])
    back = as_transform(np.array(yaml.safe_load(pose_text(T))["matrix"], dtype=float))
    dt, dr = pose_error(back, T)
    assert dt < 1e-6 and dr < 1e-8
