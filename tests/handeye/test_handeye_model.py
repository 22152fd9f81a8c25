"""The hand-eye maximum-likelihood model: its Jacobians and residuals (the SE(3) operators it chains are
tested in tests/test_transforms.py)."""

import numpy as np
import pytest
from hypothesis import strategies as st

from engine import transforms as tf
from engine.transforms import (
    retract,
)
from plugins.calibration.handeye.ml_model import EivModel
from plugins.calibration.handeye.noise import NoiseModel
from plugins.calibration.handeye.problem import model_camera_poses

finite = st.floats(-1.0, 1.0, allow_nan=False)
vec6 = st.lists(finite, min_size=6, max_size=6).map(np.array)


def random_pose(rng: np.random.Generator) -> np.ndarray:
    return tf.T_from_rotvec(rng.normal(size=3), rng.normal(size=3))


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
        retract(M, rng.normal(size=(n, 6)) * 0.05),
        retract(B, rng.normal(size=(n, 6)) * 0.05),
        noise,
        random_pose(rng),
        random_pose(rng),
        retract(M, rng.normal(size=(n, 6)) * 0.1),
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
