"""Analytic Jacobians (joints and chain parameters) against central finite differences, to 1e-6.

Twist order (v, w) and frames as documented in plugins.robot.chain: ``space`` matches the left
perturbation of engine.transforms (T(q + dq) = exp(J dq) T(q)), ``tool`` the right one, ``base`` is
the geometric Jacobian (TCP-point velocity, angular velocity, world coordinates).
"""

from __future__ import annotations

import numpy as np
import pytest

from engine.transforms import exp_se3, inv, log_se3
from plugins.robot.model_file import load_robot_model

H = 1e-6


def _numeric(fk, x, frame, n_cols, perturb):
    """Central differences of the pose, in the same twist convention as the analytic Jacobian."""
    cols = []
    for k in range(n_cols):
        Tp, Tm = fk(perturb(x, k, H)), fk(perturb(x, k, -H))
        col = np.zeros((Tp.shape[0], 6))
        for i in range(Tp.shape[0]):
            if frame == "space":
                col[i] = log_se3(Tp[i] @ inv(Tm[i])) / (2 * H)
            elif frame == "tool":
                col[i] = log_se3(inv(Tm[i]) @ Tp[i]) / (2 * H)
            else:
                col[i, :3] = (Tp[i, :3, 3] - Tm[i, :3, 3]) / (2 * H)
                col[i, 3:] = log_se3(Tp[i] @ inv(Tm[i]))[3:] / (2 * H)
        cols.append(col)
    return np.stack(cols, axis=2)


def _bump(x, k, h):
    y = x.copy()
    y[..., k] += h
    return y


@pytest.fixture(scope="module", params=["ur5e", "abb_irb120"])
def model(request):
    m = load_robot_model(request.param)
    m = m.with_tool(exp_se3([0.02, -0.01, 0.15, 0.2, -0.1, 0.3]))
    return m.with_base(exp_se3([0.4, -0.3, 0.1, 0.1, 0.05, -0.6]))


@pytest.mark.parametrize("frame", ["space", "base", "tool"])
def test_joint_jacobian_matches_finite_differences(model, frame):
    q = np.random.default_rng(0).uniform(-3, 3, size=(8, model.dof))
    J = model.jacobian(q, frame=frame)
    Jn = _numeric(model.fk, q, frame, model.dof, _bump)
    assert np.abs(J - Jn).max() < 1e-6


@pytest.mark.parametrize("frame", ["space", "base"])
def test_parameter_jacobian_matches_finite_differences(model, frame):
    q = np.random.default_rng(1).uniform(-3, 3, size=(5, model.dof))
    v0 = model.param_values
    _, J = model.param_jacobian(q, frame=frame)
    assert J.shape == (5, 6, len(model.param_names))
    Jn = _numeric(lambda v: model.fk(q, v), v0, frame, v0.size, _bump)
    assert np.abs(J - Jn).max() < 1e-6


def test_point_jacobian_matches_finite_differences(model):
    """Position-only measurements of a point on the tool: d(point)/dq and d(point)/d(params)."""
    q = np.random.default_rng(2).uniform(-3, 3, size=(5, model.dof))
    pt = np.array([0.03, -0.02, 0.05])
    Jq = model.jacobian(q, frame="base", point_tcp=pt)[:, :3]
    num = np.stack(
        [(model.tool_points(q + H * e, pt) - model.tool_points(q - H * e, pt)) / (2 * H) for e in np.eye(model.dof)],
        axis=2,
    )
    assert np.abs(Jq - num).max() < 1e-6
    _, Jp = model.param_jacobian(q, frame="base", point_tcp=pt)
    v0 = model.param_values
    nump = np.stack(
        [
            (model.tool_points(q, pt, v0 + H * e) - model.tool_points(q, pt, v0 - H * e)) / (2 * H)
            for e in np.eye(v0.size)
        ],
        axis=2,
    )
    assert np.abs(Jp[:, :3] - nump).max() < 1e-6


def test_per_sample_parameters(model):
    """values of shape (N, P) give each sample its own parameters (what thermal drift needs)."""
    rng = np.random.default_rng(3)
    q = rng.uniform(-3, 3, size=(4, model.dof))
    V = model.param_values + 1e-3 * rng.normal(size=(4, model.param_values.size))
    T = model.fk(q, V)
    for i in range(4):
        assert np.allclose(T[i], model.fk(q[i], V[i]), atol=1e-15)
