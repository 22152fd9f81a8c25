"""Degenerate motion sets are reported BEFORE solving, with the poses to add; wrong set-ups are refused."""

import numpy as np
import pytest

from engine import transforms as tf
from engine.transforms import inv
from plugins.calibration.handeye import NoiseModel, analyse_motions, calibrate_hand_eye
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.problem import model_camera_poses

NOISE = NoiseModel.isotropic(0.02, 0.1, 0.1, 0.5)


def test_rotations_about_one_axis_are_degenerate_and_the_advice_names_the_missing_axes():
    rng = np.random.default_rng(30)
    # only rolls about the optical axis (camera z = tcp z here up to the mounting rotation)
    scene = sim.viewing_scene(rng, 12, "eye_in_hand", max_tilt_deg=0.0, max_roll_deg=60.0)
    res = calibrate_hand_eye(scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand", noise=NOISE)
    assert res.verdict == "degenerate" and not res.usable
    assert res.estimate == {} and res.covariance is None  # nothing solved
    assert "one axis" in res.reasons[0]
    report = analyse_motions("eye_in_hand", scene.T_base_tcp, scene.T_cam_target)
    axis = report.weakest_direction
    roll_axis_tcp = scene.X[:3, :3] @ np.array([0.0, 0.0, 1.0])  # camera z in the tcp frame
    assert abs(axis @ roll_axis_tcp) > 0.999
    assert "perpendicular" in res.advice[0]


def test_scara_like_eye_to_hand_rotations_about_base_z_are_degenerate():
    rng = np.random.default_rng(31)
    X = tf.T_from_rotvec([np.pi, 0, 0], [0.5, 0.0, 1.2])  # camera looking down
    Y = tf.T_from_rotvec([0, 0, 0.3], [0.0, 0.0, 0.05])
    M = np.array(
        [
            tf.T_from_rotvec([0, 0, a], [0.4 + 0.2 * rng.random(), 0.2 * rng.random(), 0.3])
            for a in np.linspace(-1, 1, 8)
        ]
    )
    B = model_camera_poses("eye_to_hand", M, X, Y)
    res = calibrate_hand_eye(M, B, setup="eye_to_hand", noise=NOISE)
    assert res.verdict == "degenerate"
    assert "(+0.00, +0.00, +1.00) in the base frame" in res.reasons[0]


def test_too_little_rotation_is_degenerate():
    rng = np.random.default_rng(32)
    scene = sim.viewing_scene(rng, 12, "eye_in_hand", max_tilt_deg=1.0, max_roll_deg=1.0)
    res = calibrate_hand_eye(scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand", noise=NOISE)
    assert res.verdict == "degenerate" and "too little rotation" in res.reasons[0]
    assert "20-30 degrees" in res.advice[0]


@pytest.mark.parametrize("n", [1, 2])
def test_too_few_poses_is_degenerate(n):
    scene = sim.viewing_scene(np.random.default_rng(33), n, "eye_in_hand")
    res = calibrate_hand_eye(scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand", noise=NOISE)
    assert res.verdict == "degenerate" and "too few poses" in res.reasons[0]


def test_weak_rotation_diversity_is_a_warning_with_advice():
    rng = np.random.default_rng(34)
    scene = sim.add_noise(sim.viewing_scene(rng, 12, "eye_in_hand", max_tilt_deg=6.0, max_roll_deg=60.0), NOISE, rng)
    res = calibrate_hand_eye(scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand", noise=NOISE)
    assert res.verdict == "warning" and res.usable
    assert any("weak rotation diversity" in r for r in res.reasons)
    assert any("tilting" in a for a in res.advice)


def test_good_motion_set_is_not_flagged():
    scene = sim.viewing_scene(np.random.default_rng(35), 15, "eye_in_hand")
    rep = analyse_motions("eye_in_hand", scene.T_base_tcp, scene.T_cam_target)
    assert rep.verdict == "ok" and not rep.reasons
    assert np.rad2deg(rep.metrics["excitation_min_rad"]) > 8.0


@pytest.mark.parametrize("setup", ["eye_in_hand", "eye_to_hand"])
def test_wrong_setup_or_inverted_poses_are_refused(setup):
    rng = np.random.default_rng(36)
    scene = sim.add_noise(sim.viewing_scene(rng, 15, setup), NOISE, rng)
    other = "eye_to_hand" if setup == "eye_in_hand" else "eye_in_hand"
    wrong = calibrate_hand_eye(scene.T_base_tcp, scene.T_cam_target, setup=other, noise=NOISE)
    assert wrong.verdict == "failed" and f"the set-up is {setup}" in wrong.reasons[-1]
    inverted = calibrate_hand_eye(scene.T_base_tcp, inv(scene.T_cam_target), setup=setup, noise=NOISE)
    assert inverted.verdict == "failed" and "inverted" in inverted.reasons[-1]
    right = calibrate_hand_eye(scene.T_base_tcp, scene.T_cam_target, setup=setup, noise=NOISE)
    assert right.usable
