"""Lengths that do not fit the unit in their parameter's name are refused before a run starts."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from engine.cli.main import main
from engine.recipe.unit_checks import MAX_CELL_LENGTH_M, implausible_lengths

RECIPE = """vgr: 1
name: units
stages:
  robot: {{type: sim_robot, params: {{model: ur5e}}}}
  camera:
    type: sim_camera
    uses: {{robot: robot.truth}}
    params:
      parts: [{{name: part, workpiece: feature_part, pose: {{xyz_m: {xyz}}}}}]
"""


def test_millimetres_in_a_metre_pose_are_refused_by_validate_with_the_parameter_named(tmp_path, capsys):
    path = tmp_path / "r.yaml"
    path.write_text(RECIPE.format(xyz="[-490, -80, 0]"))
    assert main(["validate", str(path)]) == 2
    said = capsys.readouterr()
    err = said.out + said.err
    assert f"{path}:9:" in err and "stages.camera.params.parts.0.pose.xyz_m" in err
    assert "-490 m" in err and "were these millimetres?" in err
    path.write_text(RECIPE.format(xyz="[-0.49, -0.08, 0]"))
    assert main(["validate", str(path)]) == 0


def test_an_override_in_the_wrong_unit_is_refused_too(capsys):
    argv = ["validate", "recipes/eye_in_hand_dock.yaml", "-p", "guidance.max_step_mm=0.00005"]
    assert main(argv) == 2
    out = capsys.readouterr()
    assert "below a micron: were these metres? max_step_mm is in millimetres" in out.out + out.err


@given(st.lists(st.floats(-MAX_CELL_LENGTH_M, MAX_CELL_LENGTH_M, allow_nan=False), min_size=1, max_size=6))
def test_lengths_within_a_cell_pass(values):
    assert list(implausible_lengths({"pose": {"xyz_m": values}, "translation_m": values[0]})) == []


@pytest.mark.parametrize(
    ("params", "where"),
    [
        ({"pose": {"xyz_m": [0.1, 25.0, 0]}}, ("pose", "xyz_m")),
        ({"parts": [{"pose": {"xyz_m": [470, 0, 0]}}]}, ("parts", 0, "pose", "xyz_m")),
        ({"approach_mm": 0.0002}, ("approach_mm",)),
    ],
)
def test_each_implausible_length_is_found_where_it_is(params, where):
    assert [w for w, _ in implausible_lengths(params)] == [where]


def test_other_keys_zero_and_flags_are_not_lengths():
    params = {"rate_hz": 500.0, "count": 1000, "approach_mm": 0.0, "enabled_m": True, "name_m": "x" * 30}
    assert list(implausible_lengths(params)) == []
