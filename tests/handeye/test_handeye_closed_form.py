"""Closed-form initialisers: exact on exact data, and the pitfalls OpenCV had (q/-q, 0 and 180 degrees)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from engine import transforms as tf
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.closed_form import CLOSED_FORM_METHODS, closed_form
from plugins.calibration.handeye.noise import NoiseModel
from plugins.calibration.handeye.problem import model_camera_poses

EXACT_M, EXACT_RAD = 1e-9, 1e-9


def _errors(method, scene):
    X, Y = closed_form(scene.setup, scene.T_base_tcp, scene.T_cam_target, method)
    return tf.pose_error(X, scene.X), tf.pose_error(Y, scene.Y)


@pytest.mark.parametrize("method", CLOSED_FORM_METHODS)
@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_exact_data_give_exact_solution(method, setup):
    scene = sim.viewing_scene(np.random.default_rng(10), 8, setup)
    (tx, rx), (ty, ry) = _errors(method, scene)
    assert tx < EXACT_M and rx < EXACT_RAD and ty < EXACT_M and ry < EXACT_RAD


@pytest.mark.parametrize("method", CLOSED_FORM_METHODS)
@pytest.mark.parametrize("angle_deg", [179.0, 180.0])
def test_hand_eye_rotation_near_180_degrees(method, angle_deg):
    # Tsai-Lenz's Gibbs vector tan(theta/2) diverges at 180 degrees
    X = tf.T_from_rotvec(np.deg2rad(angle_deg) * np.array([0.6, -0.48, 0.64]), [0.1, 0.2, 0.3])
    scene = sim.viewing_scene(np.random.default_rng(11), 8, "eye_in_hand", X=X)
    (tx, rx), _ = _errors(method, scene)
    assert tx < 1e-8 and rx < 1e-8


def _scene_with_half_turns(rng, noise_deg: float):
    """Robot poses differing by rotations of about 180 degrees, where q and -q are ambiguous."""
    X = tf.T_from_rotvec([0.3, -0.2, 0.5], [0.05, 0.02, 0.1])
    Y = tf.T_from_rotvec([0.1, 0.2, -0.3], [0.8, 0.1, 0.3])
    base = Rotation.from_rotvec([0.2, 0.1, 0.0])
    M = []
    for k in range(10):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        # odd poses: half turns; every (even, odd) pair is a 180-degree relative motion
        R = (Rotation.from_rotvec(axis * (np.pi if k % 2 else 0.0)) * base).as_matrix()
        M.append(tf.T_from_Rt(R, np.array([0.5, 0.0, 0.4]) + rng.uniform(-0.3, 0.3, size=3)))
    M = np.array(M)
    B = model_camera_poses("eye_in_hand", M, X, Y)
    scene = sim.Scene("eye_in_hand", M, B, X, Y)
    if noise_deg > 0:
        scene = sim.add_noise(scene, NoiseModel.isotropic(0.0, 0.0, noise_deg, 0.1), rng)
        scene = sim.Scene("eye_in_hand", scene.T_base_tcp, scene.T_cam_target, X, Y)
    return scene


@pytest.mark.parametrize("method", CLOSED_FORM_METHODS)
def test_relative_motions_near_180_degrees(method):
    rng = np.random.default_rng(12)
    exact = _scene_with_half_turns(rng, 0.0)
    (tx, rx), _ = _errors(method, exact)
    assert tx < 1e-8 and rx < 1e-8
    # with noise the sign of near-180 quaternions flips at random; a wrong sign costs degrees
    noisy = _scene_with_half_turns(rng, 0.05)
    (tx, rx), _ = _errors(method, noisy)
    assert np.rad2deg(rx) < 0.2 and tx < 0.01


def test_opencv_regression_24871_configuration():
    # the configuration of OpenCV's regression test: hand-eye rotation of 120 degrees, 4 poses,
    # exact data, where most OpenCV 4.x methods failed before their fix
    X = np.array([[0.0, 0.0, -1.0, 0.1], [1.0, 0.0, 0.0, 0.2], [0.0, -1.0, 0.0, 0.3], [0, 0, 0, 1.0]])
    rng = np.random.default_rng(13)
    for trial in range(20):
        scene = sim.opencv_protocol(rng, 4, noise=False)
        scene = sim.Scene(
            "eye_in_hand",
            scene.T_base_tcp,
            model_camera_poses("eye_in_hand", scene.T_base_tcp, X, scene.Y),
            X,
            scene.Y,
        )
        for method in CLOSED_FORM_METHODS:
            (tx, rx), _ = _errors(method, scene)
            assert tx < 1e-9 and rx < 1e-9, (trial, method)


def test_small_relative_rotations_do_not_spoil_the_estimate():
    # pairs of nearly identical poses (re-measurements) add only noise to the linear systems
    rng = np.random.default_rng(14)
    scene = sim.viewing_scene(rng, 8, "eye_in_hand")
    M = np.concatenate([scene.T_base_tcp, scene.T_base_tcp @ tf.T_from_rotvec([1e-4, 0, 0], [1e-4, 0, 0])])
    B = model_camera_poses("eye_in_hand", M, scene.X, scene.Y)
    noisy = sim.add_noise(
        sim.Scene("eye_in_hand", M, B, scene.X, scene.Y), NoiseModel.isotropic(0.01, 0.05, 0.05, 0.2), rng
    )
    for method in CLOSED_FORM_METHODS:
        (tx, rx), _ = _errors(method, sim.Scene("eye_in_hand", noisy.T_base_tcp, noisy.T_cam_target, scene.X, scene.Y))
        assert tx < 0.005 and np.rad2deg(rx) < 0.3, method
