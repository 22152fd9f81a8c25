"""Effects as fittable models: pack/unpack, declared parameters, Jacobians, a least-squares fit,
the catalog and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from plugins.robot.effects import (
    CATALOG,
    Backlash,
    BaseFrameError,
    EncoderEccentricity,
    GeometricErrors,
    JointCompliance,
    JointOffset,
    LinkLength,
    SampleContext,
    TemperatureExpansion,
    ThermalDrift,
    ToolOffsetError,
    effect_from_config,
    effects_from_config,
)
from plugins.robot.model_file import load_robot_model
from plugins.robot.with_effects import RobotWithEffects

UR5E = load_robot_model("ur5e")
RNG = np.random.default_rng(0)
Q = RNG.uniform(-np.pi, np.pi, size=(40, 6))
CTX = SampleContext(
    t_s=RNG.uniform(0, 7200, 40),
    direction=np.sign(RNG.normal(size=(40, 6))),
    payload_kg=RNG.uniform(0, 3, 40),
    temp_c=RNG.uniform(18, 32, 40),
)

EFFECTS = [
    GeometricErrors.from_dict({"joint2.a": 2e-4, "joint3.alpha": -1e-4, "joint4.beta": 5e-5}),
    JointOffset((2, 5), (1e-4, -2e-4)),
    LinkLength((3,), (3e-4,)),
    BaseFrameError(offsets=(1e-4, -2e-4, 3e-4, 1e-4, 0.0, -1e-4)),
    ToolOffsetError(("tx", "ty", "tz"), (1e-4, 2e-4, -3e-4)),
    JointCompliance((2, 3), (2e-6, 3e-6)),
    Backlash((1, 2), (3e-4, 2e-4)),
    EncoderEccentricity((1, 6), (5e-5, 1e-4), (-2e-5, 3e-5)),
    ThermalDrift(("joint2.a", "joint3.a", "base.tz"), (-1e-4, -8e-5, 5e-5), 1500.0),
    TemperatureExpansion(("joint2.a", "joint4.d"), (-9e-6, 3e-6), 21.0),
]


def test_every_catalog_effect_is_covered():
    assert {type(e) for e in EFFECTS} == set(CATALOG.values())


@pytest.mark.parametrize("effect", EFFECTS, ids=lambda e: e.catalog_name)
def test_pack_unpack_and_declarations(effect):
    x = effect.pack()
    specs = effect.param_specs()
    assert x.shape == (len(specs),) == (effect.n_params,)
    assert len({s.name for s in specs}) == len(specs)
    assert all(s.unit in ("m", "rad", "s", "rad/(N m)", "m/K", "rad/K") for s in specs)
    assert effect.unpack(x) == effect
    y = x + 1e-6
    assert np.allclose(effect.unpack(y).pack(), y)
    lo, hi = effect.param_bounds()
    assert lo.shape == hi.shape == x.shape and np.all(lo <= x) and np.all(x <= hi)
    d = effect.describe()
    assert d["name"] == effect.catalog_name and set(d["params"]) == {s.name for s in specs}
    places = effect.where.split(",")
    assert places and len(set(places)) == len(places)
    assert all(p in ("base", "tool") or p.startswith("joint") for p in places)


@pytest.mark.parametrize("index", range(len(EFFECTS)), ids=[e.catalog_name for e in EFFECTS])
def test_effect_jacobian_matches_finite_differences(index):
    robot = RobotWithEffects(UR5E, EFFECTS)
    J = robot.effect_jacobian(index, Q, CTX)
    effect = EFFECTS[index]
    x = effect.pack()
    for k in range(x.size):
        h = 1e-6 * max(1.0, abs(x[k]))
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        pp = robot.replace_effect(index, effect.unpack(xp)).fk(Q, CTX)[:, :3, 3]
        pm = robot.replace_effect(index, effect.unpack(xm)).fk(Q, CTX)[:, :3, 3]
        num = (pp - pm) / (2 * h)
        assert np.abs(num - J[:, :3, k]).max() <= 1e-6 * max(1.0, np.abs(num).max())


def test_an_effect_is_fitted_by_least_squares_from_positions():
    """What the model-gap workflow does: the true compliance is hidden in data; fit it with pack/unpack + Jacobian."""
    truth = JointCompliance((2, 3), (2.5e-6, 4e-6))
    rng = np.random.default_rng(5)
    q = rng.uniform(-np.pi, np.pi, size=(150, 6))
    ctx = SampleContext(payload_kg=np.full(150, 3.0))
    noise_m = 2e-6
    meas = RobotWithEffects(UR5E, [truth]).fk(q, ctx)[:, :3, 3] + rng.normal(0, noise_m, (150, 3))
    guess = JointCompliance((2, 3), (0.0, 0.0))

    def residual(x):
        return (RobotWithEffects(UR5E, [guess.unpack(x)]).fk(q, ctx)[:, :3, 3] - meas).ravel()

    def jac(x):
        return RobotWithEffects(UR5E, [guess.unpack(x)]).effect_jacobian(0, q, ctx)[:, :3].reshape(-1, x.size)

    sol = least_squares(residual, guess.pack(), jac=jac, bounds=guess.param_bounds(), x_scale=1e-6)
    fitted = guess.unpack(sol.x)
    assert np.allclose(fitted.compliance_rad_per_nm, truth.compliance_rad_per_nm, rtol=0.02)
    assert np.sqrt(np.mean(sol.fun**2)) < 1.2 * noise_m


def test_catalog_config_and_unknown_names():
    effects = effects_from_config(
        {
            "joint_compliance": {"joints": [2, 3], "compliance_rad_per_nm": [2e-6, 3e-6]},
            "backlash": {"joints": [1], "width_rad": [2e-4]},
            "geometric_errors": {"offsets": {"joint2.a": 1e-4}},
        }
    )
    assert [e.catalog_name for e in effects] == ["joint_compliance", "backlash", "geometric_errors"]
    assert effects[0].where == "joint2,joint3"
    with pytest.raises(ValueError, match="did you mean 'backlash'"):
        effect_from_config("backlsh", {})
    with pytest.raises(ValueError, match="unexpected keyword"):
        effect_from_config("backlash", {"joint": [1]})


def test_effects_are_checked_against_the_model():
    with pytest.raises(ValueError, match="do not exist"):
        RobotWithEffects(UR5E, [Backlash((7,), (1e-4,))])
    with pytest.raises(ValueError, match="did you mean"):
        RobotWithEffects(UR5E, [GeometricErrors.from_dict({"joint2.aa": 1e-4})])
    with pytest.raises(ValueError, match="link masses"):
        RobotWithEffects(UR5E.with_links(None), [JointCompliance((2,), (1e-6,))])
    with pytest.raises(ValueError, match="dh/mdh"):
        RobotWithEffects(UR5E.to_convention("poe"), [LinkLength((2,), (1e-4,))])
    with pytest.raises(TypeError):
        RobotWithEffects(UR5E, ["backlash"])


bad_float = st.sampled_from([np.nan, np.inf, -np.inf])


@given(bad_float)
@settings(max_examples=10, deadline=None)
def test_non_finite_parameters_are_rejected(bad):
    for make in (
        lambda: JointCompliance((2,), (bad,)),
        lambda: Backlash((2,), (bad,)),
        lambda: EncoderEccentricity((2,), (bad,), (0.0,)),
        lambda: GeometricErrors(("joint2.a",), (bad,)),
        lambda: ToolOffsetError(("tx",), (bad,)),
        lambda: ThermalDrift(("joint2.a",), (bad,)),
        lambda: ThermalDrift(("joint2.a",), (1e-4,), bad),
    ):
        with pytest.raises(ValueError):
            make()
    with pytest.raises(ValueError, match="NaN"):
        EFFECTS[0].unpack(np.full(3, bad))


@given(st.integers(0, 4).filter(lambda n: n != 2))
@settings(max_examples=10, deadline=None)
def test_wrong_lengths_are_rejected(n):
    with pytest.raises(ValueError, match="one value per joint"):
        JointCompliance((2, 3), (1e-6,) * n)
    with pytest.raises(ValueError, match="parameters"):
        Backlash((2, 3), (1e-4, 1e-4)).unpack(np.zeros(n))


def test_other_bad_structure():
    with pytest.raises(ValueError, match="1-based"):
        Backlash((0,), (1e-4,))
    with pytest.raises(ValueError, match="unique"):
        Backlash((2, 2), (1e-4, 1e-4))
    with pytest.raises(ValueError, match=">= 0"):
        Backlash((2,), (-1e-4,))
    with pytest.raises(ValueError, match="components"):
        ToolOffsetError(("tq",), (0.0,))
    with pytest.raises(ValueError, match="time constant"):
        ThermalDrift((), (), 0.0)
    with pytest.raises(ValueError, match="broadcast"):
        RobotWithEffects(UR5E, [Backlash((1,), (1e-4,))]).fk(Q[:3], SampleContext(direction=np.ones((2, 6))))
