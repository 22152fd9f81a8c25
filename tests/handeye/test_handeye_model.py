"""The SE(3) machinery under the hand-eye ML: decoupled perturbations, chain operators, Jacobians."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import transforms as tf
from plugins.solvers.handeye import lie
from plugins.solvers.handeye.ml_model import EivModel
from plugins.solvers.handeye.noise import NoiseModel
from plugins.solvers.handeye.problem import model_camera_poses

finite = st.floats(-1.0, 1.0, allow_nan=False)
vec6 = st.lists(finite, min_size=6, max_size=6).map(np.array)


def random_pose(rng: np.random.Generator) -> np.ndarray:
    return tf.T_from_rotvec(rng.normal(size=3), rng.normal(size=3))


@settings(max_examples=50)
@given(vec6, vec6)
def test_pose_delta_inverts_retract(d, seed_vec):
    rng = np.random.default_rng(int(abs(seed_vec[0]) * 1e6))
    T = random_pose(rng)[None]
    d = d * np.array([1, 1, 1, 2.5, 2.5, 2.5]) / 1.8  # rotations up to ~2.4 rad
    assert np.allclose(lie.pose_delta(lie.retract(T, d[None]), T)[0], d, atol=1e-9)


def test_so3_jacobians_match_their_definitions():
    rng = np.random.default_rng(0)
    for w in [rng.normal(size=3), np.array([0.0, 0.0, 1e-9]), np.array([0.0, 3.0, 0.0])]:
        d = rng.normal(size=3) * 1e-6
        # exp(w + d) = exp(J_l(w) d) exp(w)
        lhs = tf.exp_so3(w + d)
        rhs = tf.exp_so3(lie.so3_left_jacobian(w)[0] @ d) @ tf.exp_so3(w)
        assert np.allclose(lhs, rhs, atol=1e-11)
        # exp(w) exp(d) = exp(w + J_r^-1(w) d)
        lhs = tf.exp_so3(w) @ tf.exp_so3(d)
        rhs = tf.exp_so3(w + lie.so3_right_jacobian_inv(w)[0] @ d)
        assert np.allclose(lhs, rhs, atol=1e-11)


def _numeric_dd(f, T: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """6x6 numeric derivative of pose_delta(f(retract(T, d)), f(T)) at d = 0."""
    base = f(T[None])
    J = np.zeros((6, 6))
    for k in range(6):
        d = np.zeros((1, 6))
        d[0, k] = h
        J[:, k] = (
            lie.pose_delta(f(lie.retract(T[None], d)), base)[0] - lie.pose_delta(f(lie.retract(T[None], -d)), base)[0]
        ) / (2 * h)
    return J


def test_chain_operators_match_numeric_derivatives():
    rng = np.random.default_rng(1)
    P, Q = random_pose(rng), random_pose(rng)
    assert np.allclose(lie.d_product_left(P, Q)[0], _numeric_dd(lambda X: X @ Q, P), atol=1e-7)
    assert np.allclose(lie.d_product_right(P)[0], _numeric_dd(lambda X: P @ X, Q), atol=1e-7)
    assert np.allclose(lie.d_inverse(P)[0], _numeric_dd(lie.inv_batch, P), atol=1e-7)


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("robot_deg", [0.02, 0.0])
def test_eiv_jacobian_matches_finite_differences(setup, robot_deg):
    rng = np.random.default_rng(2)
    n = 4
    X, Y = random_pose(rng), random_pose(rng)
    M = np.stack([random_pose(rng) for _ in range(n)])
    B = model_camera_poses(setup, M, X, Y)
    noise = NoiseModel.isotropic(robot_deg, robot_deg * 5, 0.1, 0.5)
    model = EivModel(
        setup,
        lie.retract(M, rng.normal(size=(n, 6)) * 0.05),
        lie.retract(B, rng.normal(size=(n, 6)) * 0.05),
        noise,
        random_pose(rng),
        random_pose(rng),
        lie.retract(M, rng.normal(size=(n, 6)) * 0.1),
    )
    x = rng.normal(size=model.n_params) * 0.3
    sqrt_w = np.sqrt(rng.uniform(0.5, 1.0, size=n))
    J = model.jacobian_matrix(x, sqrt_w, as_sparse=False)
    Jn = np.zeros_like(J)
    h = 1e-6
    for k in range(model.n_params):
        d = np.zeros_like(x)
        d[k] = h
        Jn[:, k] = (model.residual_vector(x + d, sqrt_w) - model.residual_vector(x - d, sqrt_w)) / (2 * h)
    assert np.max(np.abs(J - Jn)) < 1e-8 * np.max(np.abs(J))
    if model.robot_free:
        assert np.allclose(model.jacobian_matrix(x, sqrt_w, as_sparse=True).toarray(), J)


def test_model_residuals_vanish_at_the_truth():
    rng = np.random.default_rng(3)
    X, Y = random_pose(rng), random_pose(rng)
    M = np.stack([random_pose(rng) for _ in range(5)])
    for setup in ("eye_in_hand", "eye_to_hand"):
        B = model_camera_poses(setup, M, X, Y)
        model = EivModel(setup, M, B, NoiseModel.isotropic(0.01, 0.1, 0.1, 0.5), X, Y)
        assert np.max(np.abs(model.residual_vector(np.zeros(model.n_params), np.ones(5)))) < 1e-9
