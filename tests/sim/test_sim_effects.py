"""Sensor-side injectable effects: each one's signature in the data, and their recipe form.

Renders are noiseless here so each signature is shown exactly: the captured points lie on the part at
the pose the effect predicts (to float32 ray-casting precision, < 1 um) and visibly off the nominal
pose.  The hand-eye test also fits the part by ICP to show the displacement a solver would measure.
"""

import math

import numpy as np
import open3d as o3d
import pytest
from simcam_helpers import fit_part_pose, on_surface_distance, surface_scene

from engine.transforms import T_from_rotvec, inv, pose_error
from plugins.camera.pinhole import CameraModel
from plugins.sim.camera import DepthCameraModel, DepthNoiseModel, look_at
from plugins.sim.cell import CameraMount, PartPlacement, SimCell
from plugins.sim.sensor_effects import CameraEffects, PoseOffset, SensorEffects, TrackerEffects
from plugins.util.workpieces import make_workpiece

MM = 1e-3
INTRINSICS = CameraModel.pinhole(320, 240, 277.1, 277.1, 159.5, 119.5)
T_WORLD_PART = T_from_rotvec([0.0, 0.0, 0.3], [0.55, 0.05, 0.0])
T_WORLD_TCP = look_at([0.75, 0.25, 0.5], [0.55, 0.05, 0.03])  # the TCP looks at the part
T_TCP_CAM = T_from_rotvec([0.0, 0.0, 0.05], [0.03, -0.02, 0.05])
HAND_EYE_ERROR = PoseOffset((0.002, -0.001, 0.0015), (0.004, -0.006, 0.008))  # ~2.7 mm, ~0.6 deg
PLACEMENT_ERROR = PoseOffset((0.003, 0.002, 0.0), (0.0, 0.0, math.radians(1.5)))


@pytest.fixture(scope="module")
def part():
    return make_workpiece("feature_part")


def _cell(part, effects=None, mount=None, parent="world", T_parent_part=T_WORLD_PART) -> SimCell:
    camera = DepthCameraModel(INTRINSICS, DepthNoiseModel.noiseless())
    return SimCell(
        camera,
        mount if mount is not None else CameraMount.eye_in_hand(T_TCP_CAM),
        [PartPlacement("part", part, T_parent_part, parent)],
        effects,
    )


def _on_pose(part, points, T_cam_part) -> float:
    return float(on_surface_distance(part, points, T_cam_part).max())


def _off(part, points, T_cam_part) -> float:
    """Largest distance (m) of the points from the part at T_cam_part: how visibly they miss it."""
    return float(
        surface_scene(part, T_cam_part).compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy().max()
    )


def test_no_effect_means_truth_equals_nominal(part):
    cap, truth = _cell(part).capture(T_WORLD_TCP, np.random.default_rng(0))
    np.testing.assert_allclose(truth.T_world_cam, truth.T_world_cam_nominal, atol=1e-15)
    np.testing.assert_allclose(truth.T_world_parts["part"], truth.T_world_parts_nominal["part"], atol=1e-15)
    T_cam_part_nominal = inv(truth.T_world_cam_nominal) @ T_WORLD_PART
    assert len(cap.points) > 3000
    assert _on_pose(part, cap.points, T_cam_part_nominal) < 1e-6


def test_hand_eye_error_displaces_the_part_by_exactly_the_injected_error(part):
    E = HAND_EYE_ERROR.matrix()
    cell = _cell(part, SensorEffects(camera=CameraEffects(hand_eye_error=HAND_EYE_ERROR)))
    cap, truth = cell.capture(T_WORLD_TCP, np.random.default_rng(0))
    T_cam_part_nominal = inv(T_WORLD_TCP @ T_TCP_CAM) @ T_WORLD_PART
    predicted = inv(E) @ T_cam_part_nominal  # the true camera is T_tcp_cam @ E
    assert _on_pose(part, cap.points, predicted) < 1e-6
    assert _off(part, cap.points, T_cam_part_nominal) > 1.0 * MM
    # what a solver measures: ICP from the nominal pose converges to the displaced one
    T_fit = fit_part_pose(cap.points, part, T_cam_part_nominal)
    dt, dr = pose_error(T_fit, predicted)
    assert dt < 0.02 * MM and math.degrees(dr) < 0.005
    # mapped through the nominal camera pose, the part appears moved by T_wc E^-1 T_wc^-1
    T_world_cam_nominal = truth.T_world_cam_nominal
    apparent = T_world_cam_nominal @ T_fit @ inv(T_WORLD_PART)
    expected = T_world_cam_nominal @ inv(E) @ inv(T_world_cam_nominal)
    dt, dr = pose_error(apparent, expected)
    assert dt < 0.05 * MM and math.degrees(dr) < 0.005  # 0.003 deg of ICP at a 0.6 m lever ~ 30 um


def test_hand_eye_error_of_a_fixed_camera(part):
    T_world_cam = look_at([0.9, 0.3, 0.6], [0.55, 0.05, 0.03])
    cell = _cell(
        part,
        SensorEffects(camera=CameraEffects(hand_eye_error=HAND_EYE_ERROR)),
        mount=CameraMount.eye_to_hand(T_world_cam),
    )
    cap, truth = cell.capture(None, np.random.default_rng(0))
    np.testing.assert_allclose(truth.T_world_cam, T_world_cam @ HAND_EYE_ERROR.matrix(), atol=1e-15)
    predicted = inv(HAND_EYE_ERROR.matrix()) @ inv(T_world_cam) @ T_WORLD_PART
    assert _on_pose(part, cap.points, predicted) < 1e-6
    assert _off(part, cap.points, inv(T_world_cam) @ T_WORLD_PART) > 1.0 * MM


def test_placement_offset_moves_the_part_by_exactly_the_injected_offset(part):
    cell = _cell(part, SensorEffects(placement={"part": PLACEMENT_ERROR}))
    cap, truth = cell.capture(T_WORLD_TCP, np.random.default_rng(0))
    np.testing.assert_allclose(truth.T_world_parts["part"], T_WORLD_PART @ PLACEMENT_ERROR.matrix(), atol=1e-15)
    T_cam_part_nominal = inv(T_WORLD_TCP @ T_TCP_CAM) @ T_WORLD_PART
    assert _on_pose(part, cap.points, T_cam_part_nominal @ PLACEMENT_ERROR.matrix()) < 1e-6
    assert _off(part, cap.points, T_cam_part_nominal) > 1.0 * MM


@pytest.mark.parametrize("speed", [0.05, 0.2])
def test_camera_latency_lags_by_velocity_times_latency(part, speed):
    """Robot moving at `speed` along world x; the frame stamped t shows the world at t - 30 ms.

    Mapped with the TCP pose at the stamp, the part appears displaced by +v * latency: the points
    lie exactly on the shifted part, and miss the believed pose by exactly v * latency.
    """
    latency = 0.030
    v = np.array([speed, 0.0, 0.0])

    def T_world_tcp(t: float) -> np.ndarray:
        T = T_WORLD_TCP.copy()
        T[:3, 3] += v * t
        return T

    cell = _cell(part, SensorEffects(camera=CameraEffects(latency_s=latency)))
    t = 1.0
    cap, truth = cell.capture(T_world_tcp, np.random.default_rng(0), t=t)
    assert cap.stamp_ns == 1_000_000_000 and truth.exposure_s == pytest.approx(t - latency)
    T_world_cam_at_stamp = T_world_tcp(t) @ T_TCP_CAM
    shifted_part = T_WORLD_PART.copy()
    shifted_part[:3, 3] += v * latency
    assert _on_pose(part, cap.points, inv(T_world_cam_at_stamp) @ shifted_part) < 1e-6
    lag = speed * latency
    assert _off(part, cap.points, inv(T_world_cam_at_stamp) @ T_WORLD_PART) == pytest.approx(lag, rel=0.02)


def test_latency_moves_a_gripped_part_seen_by_a_fixed_camera(part):
    """Eye-to-hand with the part in the gripper (seed 004's set-up): the part lags the robot."""
    latency, speed = 0.02, 0.1
    T_world_cam = look_at([0.9, 0.3, 0.6], [0.55, 0.05, 0.25])
    T_tcp_part = T_from_rotvec([math.pi, 0.0, 0.0], [0.0, 0.0, 0.1])

    def T_world_tcp(t: float) -> np.ndarray:
        return T_from_rotvec([math.pi, 0.0, 0.0], [0.55 + speed * t, 0.05, 0.35])

    cell = _cell(
        part,
        SensorEffects(camera=CameraEffects(latency_s=latency)),
        mount=CameraMount.eye_to_hand(T_world_cam),
        parent="tcp",
        T_parent_part=T_tcp_part,
    )
    cap, _ = cell.capture(T_world_tcp, np.random.default_rng(0), t=0.5)
    seen_at = inv(T_world_cam) @ T_world_tcp(0.5 - latency) @ T_tcp_part
    assert _on_pose(part, cap.points, seen_at) < 1e-6
    believed = inv(T_world_cam) @ T_world_tcp(0.5) @ T_tcp_part
    assert _off(part, cap.points, believed) == pytest.approx(speed * latency, rel=0.02)


def test_depth_effects_in_the_cell_compose_with_the_camera_model(part):
    effects = SensorEffects(camera=CameraEffects(depth_scale=1.01, depth_bias_m=0.001))
    cell = _cell(part, effects)
    cap, truth = cell.capture(T_WORLD_TCP, np.random.default_rng(0))
    r_true = np.linalg.norm(truth.render.points_true, axis=1)
    r_meas = np.linalg.norm(cap.points, axis=1)
    np.testing.assert_allclose(r_meas, 1.01 * r_true + 0.001, atol=1e-9)
    # the nominal camera model itself is untouched
    assert cell.camera.noise.depth_scale == 1.0
    stacked = CameraEffects(depth_scale=2.0, depth_bias_m=0.5).apply_to_noise(
        DepthNoiseModel(depth_scale=1.5, depth_bias_m=0.1)
    )
    assert stacked.depth_scale == 3.0 and stacked.depth_bias_m == pytest.approx(0.7)


def test_effects_default_off_and_recipe_mapping():
    off = SensorEffects()
    assert off.camera == CameraEffects() and off.tracker == TrackerEffects() and not off.placement
    assert off.camera.hand_eye_error.is_identity and off.placement_of("anything").is_identity
    assert SensorEffects.from_dict(None) == off and SensorEffects.from_dict({}) == off
    recipe = {
        "camera": {
            "depth_scale": 1.002,
            "latency_s": 0.03,
            "hand_eye_error": {"translation_m": [0.001, 0, 0], "rotation_rotvec_rad": [0, 0, 0.01]},
        },
        "placement": {"plate": {"translation_m": [0, 0.002, 0]}},
        "tracker": {"latency_s": 0.01, "dropout_prob": 0.05},
    }
    effects = SensorEffects.from_dict(recipe)
    assert effects.camera.depth_scale == 1.002 and effects.camera.latency_s == 0.03
    np.testing.assert_allclose(effects.camera.hand_eye_error.matrix()[:3, 3], [0.001, 0, 0])
    assert effects.placement_of("plate").translation_m == (0.0, 0.002, 0.0)
    assert effects.tracker.latency_s == 0.01
    np.testing.assert_allclose(PoseOffset.from_matrix(HAND_EYE_ERROR.matrix()).matrix(), HAND_EYE_ERROR.matrix())


@pytest.mark.parametrize(
    ("mapping", "error"),
    [
        ({"camera": {"depth_scal": 1.0}}, "unknown key"),
        ({"camera": {"depth_scale": 0.0}}, "positive"),
        ({"camera": {"latency_s": -0.01}}, ">= 0"),
        ({"camera": {"hand_eye_error": {"translation_m": [0, 0]}}}, "3 finite numbers"),
        ({"camera": {"hand_eye_error": {"rotation_rotvec_rad": [0, float("nan"), 0]}}}, "3 finite numbers"),
        ({"tracker": {"dropout_prob": 1.0}}, r"\[0, 1\)"),
        ({"tracker": {"extra_position_sigma_m": -1.0}}, ">= 0"),
        ({"lighting": {}}, "unknown key"),
    ],
)
def test_bad_effect_parameters_are_refused(mapping, error):
    with pytest.raises(ValueError, match=error):
        SensorEffects.from_dict(mapping)


def test_placement_for_an_unknown_part_is_refused(part):
    with pytest.raises(ValueError, match="unknown parts"):
        _cell(part, SensorEffects(placement={"plate": PLACEMENT_ERROR}))
