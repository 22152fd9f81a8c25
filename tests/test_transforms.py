"""Properties of engine.transforms: inverses, exp/log, vendor 6-vector round trips."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import transforms as tf

finite = st.floats(-3.0, 3.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)


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
    assert np.allclose(tf.T_from_ur(tf.ur_from_T(T)), T, atol=1e-9)
    pos, q = tf.abb_from_T(T)
    assert np.allclose(tf.T_from_abb(pos, q), T, atol=1e-9)
    assert np.allclose(tf.T_from_kuka_abc(tf.kuka_abc_from_T(T)), T, atol=1e-9)


def test_kuka_abc_is_zyx():
    T = tf.T_from_kuka_abc([0, 0, 0, 90, 0, 0])
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
