"""Properties of engine.transforms (inverses, exp/log, SO(3) Jacobians, decoupled perturbations and
their chain operators, batch forms) and of the vendor 6-vector conversions (plugins.vendor_poses)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import transforms as tf
from plugins import vendor_poses

finite = st.floats(-3.0, 3.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
unit = st.floats(-1.0, 1.0, allow_nan=False)
vec6 = st.lists(unit, min_size=6, max_size=6).map(np.array)


def random_T(rng: np.random.Generator) -> np.ndarray:
    return tf.T_from_rotvec(rng.normal(size=3), rng.normal(size=3))


@given(vec3, vec3)
def test_exp_log_roundtrip(v, w):
    w = w * (3.0 / max(3.0, np.linalg.norm(w) + 1e-9))  # keep |w| < pi
    xi = np.concatenate([v, w])
    if np.linalg.norm(w) >= np.pi - 1e-3:
        return
    assert np.allclose(tf.log_se3(tf.exp_se3(xi)), xi, atol=1e-9)


def test_inverse_and_chain_convention():
    rng = np.random.default_rng(0)
    T_a_b, T_b_c = random_T(rng), random_T(rng)
    p_c = rng.normal(size=3)
    p_a = tf.transform_points(T_a_b @ T_b_c, p_c)[0]
    assert np.allclose(p_a, tf.transform_points(T_a_b, tf.transform_points(T_b_c, p_c))[0])
    assert np.allclose(tf.inv(T_a_b) @ T_a_b, np.eye(4), atol=1e-12)


def test_adjoint_moves_twists_between_frames():
    rng = np.random.default_rng(1)
    T = random_T(rng)
    xi = rng.normal(size=6) * 0.1
    assert np.allclose(T @ tf.exp_se3(xi) @ tf.inv(T), tf.exp_se3(tf.adjoint(T) @ xi), atol=1e-12)


@settings(max_examples=50)
@given(vec3, vec3)
def test_vendor_roundtrips(p, r):
    T = tf.T_from_rotvec(r * 0.9, p)
    assert np.allclose(vendor_poses.T_from_ur(vendor_poses.ur_from_T(T)), T, atol=1e-9)
    pos, q = vendor_poses.abb_from_T(T)
    assert np.allclose(vendor_poses.T_from_abb(pos, q), T, atol=1e-9)
    assert np.allclose(vendor_poses.T_from_kuka_abc(vendor_poses.kuka_abc_from_T(T)), T, atol=1e-9)


def test_kuka_abc_is_zyx():
    T = vendor_poses.T_from_kuka_abc([0, 0, 0, 90, 0, 0])
    assert np.allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_rotation_near_pi_is_stable():
    R = tf.exp_so3([np.pi - 1e-9, 0, 0])
    assert abs(np.linalg.norm(tf.log_so3(R)) - np.pi) < 1e-6


def test_as_transform_rejects_bad_input():
    with pytest.raises(ValueError, match="NaN"):
        tf.as_transform(np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="not a rotation"):
        bad = np.eye(4)
        bad[0, 0] = 2.0
        tf.as_transform(bad)
    with pytest.raises(ValueError, match="4x4"):
        tf.as_transform(np.eye(3))


@settings(max_examples=50, deadline=None)
@given(vec3, vec3)
def test_so3_jacobians_match_finite_differences(phi, d):
    phi = np.array(phi)
    if np.linalg.norm(phi) > 3.0:
        phi = phi * 3.0 / np.linalg.norm(phi)
    d = np.array(d) * 1e-6
    left = tf.log_so3(tf.exp_so3(phi + d) @ tf.exp_so3(phi).T)
    right = tf.log_so3(tf.exp_so3(phi).T @ tf.exp_so3(phi + d))
    assert np.allclose(left, tf.so3_left_jacobian(phi) @ d, atol=1e-11)
    assert np.allclose(right, tf.so3_right_jacobian(phi) @ d, atol=1e-11)
    assert np.allclose(tf.so3_left_jacobian_inv(phi) @ tf.so3_left_jacobian(phi), np.eye(3), atol=1e-9)


@settings(max_examples=50)
@given(vec6, vec6)
def test_pose_delta_inverts_retract(d, seed_vec):
    rng = np.random.default_rng(int(abs(seed_vec[0]) * 1e6))
    T = random_T(rng)[None]
    d = d * np.array([1, 1, 1, 2.5, 2.5, 2.5]) / 1.8  # rotations up to ~2.4 rad
    assert np.allclose(tf.pose_delta(tf.retract(T, d[None]), T)[0], d, atol=1e-9)


def test_so3_jacobians_match_their_definitions():
    rng = np.random.default_rng(0)
    for w in [rng.normal(size=3), np.array([0.0, 0.0, 1e-9]), np.array([0.0, 3.0, 0.0])]:
        d = rng.normal(size=3) * 1e-6
        # exp(w + d) = exp(J_l(w) d) exp(w)
        lhs = tf.exp_so3(w + d)
        rhs = tf.exp_so3(tf.so3_left_jacobian(w) @ d) @ tf.exp_so3(w)
        assert np.allclose(lhs, rhs, atol=1e-11)
        # exp(w) exp(d) = exp(w + J_r^-1(w) d)
        lhs = tf.exp_so3(w) @ tf.exp_so3(d)
        rhs = tf.exp_so3(w + tf.so3_right_jacobian_inv(w) @ d)
        assert np.allclose(lhs, rhs, atol=1e-11)


def _numeric_dd(f, T: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """6x6 numeric derivative of tf.pose_delta(f(tf.retract(T, d)), f(T)) at d = 0."""
    base = f(T[None])
    J = np.zeros((6, 6))
    for k in range(6):
        d = np.zeros((1, 6))
        d[0, k] = h
        J[:, k] = (
            tf.pose_delta(f(tf.retract(T[None], d)), base)[0] - tf.pose_delta(f(tf.retract(T[None], -d)), base)[0]
        ) / (2 * h)
    return J


def test_chain_operators_match_numeric_derivatives():
    rng = np.random.default_rng(1)
    P, Q = random_T(rng), random_T(rng)
    assert np.allclose(tf.d_product_left(P, Q)[0], _numeric_dd(lambda X: X @ Q, P), atol=1e-7)
    assert np.allclose(tf.d_product_right(P)[0], _numeric_dd(lambda X: P @ X, Q), atol=1e-7)
    assert np.allclose(tf.d_inverse(P)[0], _numeric_dd(tf.inv, P), atol=1e-7)


def test_so3_jacobians_batch_forms_equal_the_single_ones_and_invert_each_other_at_every_angle():
    rng = np.random.default_rng(3)
    # from 1e-10 rad to 1 rad, across the switches to the series at 1e-8 and 1e-6 rad
    w = np.concatenate([rng.normal(size=(20, 3)), np.outer(np.geomspace(1e-10, 1.0, 60), [0.3, -0.5, 0.8])])
    for f in (tf.so3_left_jacobian, tf.so3_left_jacobian_inv, tf.so3_right_jacobian, tf.so3_right_jacobian_inv):
        batch = f(w)
        assert batch.shape == (len(w), 3, 3)
        for k in range(len(w)):
            assert np.allclose(batch[k], f(w[k]), rtol=0.0, atol=1e-15)
    eye = np.eye(3)
    # the closed forms' rounding just above the switches (module docstring) stays below 1e-8
    assert np.allclose(tf.so3_left_jacobian_inv(w) @ tf.so3_left_jacobian(w), eye, rtol=0.0, atol=1e-8)
    assert np.allclose(tf.so3_right_jacobian_inv(w) @ tf.so3_right_jacobian(w), eye, rtol=0.0, atol=1e-8)
    big = np.linalg.norm(w, axis=1) > 1e-2
    assert np.allclose(tf.so3_left_jacobian_inv(w[big]) @ tf.so3_left_jacobian(w[big]), eye, rtol=0.0, atol=1e-13)
    assert np.allclose(tf.so3_right_jacobian(w), np.transpose(tf.so3_left_jacobian(w), (0, 2, 1)), atol=1e-15)


def test_batch_inverse_hat_and_log_follow_the_input_shape():
    rng = np.random.default_rng(4)
    Ts = np.stack([random_T(rng) for _ in range(5)])
    assert np.allclose(tf.inv(Ts) @ Ts, np.eye(4), atol=1e-12)
    assert all(np.array_equal(tf.inv(Ts)[k], tf.inv(Ts[k])) for k in range(5))
    w = rng.normal(size=(5, 3))
    v = rng.normal(size=3)
    assert tf.hat(w).shape == (5, 3, 3) and np.allclose(tf.hat(w) @ v, np.cross(w, v))
    assert tf.hat(w[0].reshape(3, 1)).shape == (3, 3)
    assert np.allclose(tf.log_so3(tf.exp_so3(w)), w) and tf.exp_so3(w[0]).shape == (3, 3)
    assert np.allclose(tf.rotation_angles(tf.exp_so3(w)), np.linalg.norm(w, axis=1))
