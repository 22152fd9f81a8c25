"""Model files and bad input: names, paths, schema errors, NaN joints, wrong lengths, non-rigid frames."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from plugins.robot.model_file import list_robot_models, load_robot_model, parse_angle, robot_model_from_dict

UR5E = load_robot_model("ur5e")

MINIMAL = {
    "name": "two_link",
    "convention": "dh",
    "joints": [
        {"a": 0.3, "alpha": 0, "d": 0, "lower": "-pi", "upper": "pi", "max_speed": 1, "max_accel": 2},
        {"a": 0.2, "alpha": 0, "d": 0, "lower": "-170deg", "upper": "170deg", "max_speed": 1, "max_accel": 2},
    ],
}


def test_shipped_models_are_listed_and_load():
    assert {"ur5e", "abb_irb120"} <= set(list_robot_models())
    for name in list_robot_models():
        m = load_robot_model(name)
        assert m.name == name and m.dof == 6 and m.links is not None and m.sources


def test_load_by_path(tmp_path):
    path = tmp_path / "two_link.yaml"
    path.write_text(yaml.safe_dump(MINIMAL))
    m = load_robot_model(path)
    assert m.dof == 2
    assert np.allclose(m.fk([0.0, 0.0])[:3, 3], (0.5, 0, 0))
    assert np.isclose(m.upper[1], np.radians(170))
    assert load_robot_model(str(path)).dof == 2


@pytest.mark.parametrize(("typo", "suggestion"), [("ur5", "ur5e"), ("UR5E", "ur5e"), ("abb_irb12", "abb_irb120")])
def test_unknown_name_suggests_the_nearest(typo, suggestion):
    with pytest.raises(ValueError, match=f"did you mean '{suggestion}'"):
        load_robot_model(typo)


@given(st.text(alphabet="abcdefghijklmnopqrstuvwxyz_0123456789", min_size=1, max_size=20))
@settings(max_examples=50, deadline=None)
def test_any_unknown_name_is_a_clear_error(name):
    if name in list_robot_models():
        return
    with pytest.raises(ValueError, match="unknown robot model"):
        load_robot_model(name)


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_robot_model(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ValueError, match="not valid YAML"):
        load_robot_model(bad)


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"convention": "xyz"}, "convention"),
        ({"joints": []}, "joints"),
        (
            {"joints": [{"a": 0.3, "alpha": 0, "lower": -1, "upper": 1, "max_speed": 1, "max_accel": 1}]},
            "'d'",
        ),
        ({"joints": [dict(MINIMAL["joints"][0], alpha="pi/x")]}, "expression"),
        ({"joints": [dict(MINIMAL["joints"][0], lower=1, upper=-1)]}, "lower limit"),
        ({"joints": [dict(MINIMAL["joints"][0], max_speed=-1)]}, "positive"),
        ({"joints": [dict(MINIMAL["joints"][0], a=float("nan"))]}, "finite"),
        ({"joints": [dict(MINIMAL["joints"][0], bogus=1)]}, "bogus"),
        ({"links": [{"mass": 1.0, "com_link": [0, 0, 0]}]}, "one entry per joint"),
        ({"links": [{"mass": 1.0}, {"mass": 1.0, "com_link": [0, 0, 0]}]}, "exactly one"),
        ({"home": [0.0]}, "home"),
        ({"convention": "poe"}, "axis"),
        ({"tool": {"matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}, "not a rotation"),
        ({"base": {"rpy": [0, 0, 0], "quat_xyzw": [0, 0, 0, 1]}}, "not both"),
    ],
)
def test_schema_errors_name_the_problem(patch, message):
    with pytest.raises(ValueError, match=message):
        robot_model_from_dict(MINIMAL | patch, source="test")


def test_poe_needs_flange_pose_and_unit_axes():
    poe = {
        "name": "p",
        "convention": "poe",
        "joints": [{"axis": [0, 0, 1], "point": [0, 0, 0], "lower": -1, "upper": 1, "max_speed": 1, "max_accel": 1}],
    }
    with pytest.raises(ValueError, match="flange_at_zero"):
        robot_model_from_dict(poe)
    poe["flange_at_zero"] = {"xyz": [0.1, 0, 0]}
    assert robot_model_from_dict(poe).dof == 1
    poe["joints"][0]["axis"] = [0, 0, 2]
    with pytest.raises(ValueError, match="unit vector"):
        robot_model_from_dict(poe)


def test_parse_angle():
    assert parse_angle("pi/2") == pytest.approx(np.pi / 2)
    assert parse_angle("-2*pi") == pytest.approx(-2 * np.pi)
    assert parse_angle("0.5pi") == pytest.approx(np.pi / 2)
    assert parse_angle("90deg") == pytest.approx(np.pi / 2)
    assert parse_angle(1) == 1.0
    for bad in ("pie", "pi/0", True, None, "1e"):
        with pytest.raises(ValueError):
            parse_angle(bad)


# --------------------------------------------------------------------------- bad joint input

finite = st.floats(-10, 10, allow_nan=False)


@given(st.lists(finite, min_size=6, max_size=6), st.integers(0, 5), st.sampled_from([np.nan, np.inf, -np.inf]))
@settings(max_examples=50, deadline=None)
def test_nan_or_inf_joints_are_rejected(q, k, bad):
    q = np.array(q)
    q[k] = bad
    for fn in (UR5E.fk, UR5E.jacobian, UR5E.gravity_torque):
        with pytest.raises(ValueError, match="NaN or infinity"):
            fn(q)
    with pytest.raises(ValueError, match="NaN or infinity"):
        UR5E.fk(np.vstack([np.zeros(6), q]))


@given(st.integers(0, 12).filter(lambda n: n != 6))
@settings(max_examples=20, deadline=None)
def test_wrong_number_of_joints_is_rejected(n):
    with pytest.raises(ValueError, match="6 joints"):
        UR5E.fk(np.zeros(n))
    with pytest.raises(ValueError, match="6 joints"):
        UR5E.jacobian(np.zeros((3, n)))


def test_non_numeric_and_wrong_rank_joints():
    with pytest.raises(ValueError):
        UR5E.fk(["a"] * 6)
    with pytest.raises(ValueError):
        UR5E.fk(np.zeros((2, 3, 6)))


@given(
    st.lists(st.floats(-1, 1, allow_nan=False), min_size=9, max_size=9),
    st.floats(0.05, 0.5),
)
@settings(max_examples=50, deadline=None)
def test_non_rigid_tool_and_base_are_rejected(entries, size):
    A = np.array(entries).reshape(3, 3)
    R = A + np.eye(3) * 0.1  # almost never a rotation
    if np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.isclose(np.linalg.det(R), 1, atol=1e-6):
        return
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = size
    with pytest.raises(ValueError, match=r"not a rotation|NaN"):
        UR5E.with_tool(T)
    with pytest.raises(ValueError, match=r"not a rotation|NaN"):
        UR5E.with_base(T)


def test_bad_tool_last_row_and_nan():
    T = np.eye(4)
    T[3, 0] = 1.0
    with pytest.raises(ValueError, match="last row"):
        UR5E.with_tool(T)
    T = np.eye(4)
    T[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        UR5E.with_tool(T)


def test_parameter_override_shapes_and_names():
    with pytest.raises(ValueError, match="shape"):
        UR5E.fk(np.zeros(6), np.zeros(3))
    with pytest.raises(KeyError, match="did you mean"):
        UR5E.with_param_offsets({"joint2.aa": 1e-3})
    with pytest.raises(ValueError, match="not finite"):
        UR5E.with_param_offsets({"joint2.a": np.nan})


@pytest.mark.parametrize("conv", ["dh", "mdh", "poe"])
def test_save_and_load_round_trip(tmp_path, conv):
    """A perturbed model written as a model file reads back with the same FK and gravity torque."""
    from engine.transforms import exp_se3
    from plugins.robot.model_file import save_robot_model

    rng = np.random.default_rng(0)
    m = UR5E.with_tool(exp_se3([0.01, 0.0, 0.1, 0.1, 0.0, 0.0])).with_base(exp_se3([0.1, 0.2, 0.3, 0.1, 0.2, 0.3]))
    m = m.with_param_offsets({n: 1e-3 * rng.normal() for n in m.param_names}).to_convention(conv)
    back = load_robot_model(save_robot_model(m, tmp_path / "m.yaml"))
    q = rng.uniform(-3, 3, (50, 6))
    assert back.convention == conv
    assert np.abs(back.fk(q) - m.fk(q)).max() < 1e-12
    assert np.abs(back.gravity_torque(q) - m.gravity_torque(q)).max() < 1e-9
    assert np.allclose(back.upper, m.upper) and np.allclose(back.home, m.home)
