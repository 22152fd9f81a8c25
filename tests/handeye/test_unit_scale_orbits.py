"""The unit-scale check on poses that orbit the target (a camera kept looking at a board): their
screw translations are noise, which must not read as mixed units, while a real unit error on the
same poses still does (plugins.calibration.handeye.consistency.estimate_unit_scale)."""

import numpy as np
import pytest

from engine.transforms import T_from_rotvec, inv
from plugins.calibration.handeye import HandEyeInputError, calibrate_hand_eye
from plugins.calibration.handeye.consistency import estimate_unit_scale
from plugins.camera.board_render import look_at

X = T_from_rotvec([0.01, -0.02, 0.015], [0.004, 0.062, 0.037])  # T_tcp_cam
Y = T_from_rotvec([0.0, 0.0, 0.17], [-0.57, -0.15, 0.0])  # T_base_target


def orbits(seed: int, z_noise_m: float) -> tuple[np.ndarray, np.ndarray]:
    """12 views from 0.4 m, tilted up to 30 deg, each looking at the target's centre (pure orbits),
    the camera's depth noisy by ``z_noise_m``, the robot by 0.03 mm."""
    rng = np.random.default_rng(seed)
    M, B = [], []
    for _ in range(12):
        tilt, az = np.radians(rng.uniform(5, 30)), rng.uniform(0, 2 * np.pi)
        eye = 0.4 * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        roll = rng.uniform(0, 2 * np.pi)
        T_cam_target = look_at(eye, (0.0, 0.0, 0.0), (np.cos(roll), np.sin(roll), 0.0))
        T_base_tcp = Y @ inv(T_cam_target) @ inv(X)
        T_base_tcp[:3, 3] += rng.normal(0.0, 3e-5, 3)  # the robot repeats to ~0.03 mm
        M.append(T_base_tcp)
        noisy = T_cam_target.copy()
        noisy[:3, 3] += rng.normal(0.0, [2e-5, 2e-5, z_noise_m])
        noisy[:3, :3] = T_from_rotvec(rng.normal(0.0, 3e-4, 3), np.zeros(3))[:3, :3] @ noisy[:3, :3]
        B.append(noisy)
    return np.stack(M), np.stack(B)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_orbit_poses_with_depth_noise_are_not_mixed_units(seed):
    M, B = orbits(seed, 3e-4)
    unit = estimate_unit_scale("eye_in_hand", M, B)
    assert unit is None or abs(unit[0] - 1.0) <= 5 * unit[1]  # unobservable, or 1 within its spread
    res = calibrate_hand_eye(M, B, setup="eye_in_hand")  # raised "mixed length units" before
    assert not any("scaled" in r for r in res.reasons), res.reasons
    assert np.linalg.norm(res.estimate["T_tcp_cam"][:3, 3] - X[:3, 3]) < 2e-3


@pytest.mark.parametrize("factor", [1000.0, 0.001])
def test_a_real_unit_error_on_orbit_poses_is_still_caught(factor):
    M, B = orbits(5, 3e-4)
    M[:, :3, 3] *= factor
    with pytest.raises(HandEyeInputError, match=r"millimetres|units"):
        calibrate_hand_eye(M, B, setup="eye_in_hand")
