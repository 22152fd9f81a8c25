"""The cell description: frame tree, mounts, gripped parts, tracker following the robot, bad input."""

import math

import numpy as np
import pytest

from engine.transforms import T_from_rotvec, inv
from plugins.camera.pinhole import CameraModel
from plugins.sim.camera import DepthCameraModel, DepthNoiseModel, look_at
from plugins.sim.cell import CameraMount, PartPlacement, SimCell, TrackerMount
from plugins.sim.sensor_effects import CameraEffects, PoseOffset, SensorEffects, TrackerEffects
from plugins.sim.tracker import ViveTrackerModel
from plugins.util.workpieces import assembled_plate_pose, make_workpiece

INTRINSICS = CameraModel.pinhole(160, 120, 138.6, 138.6, 79.5, 59.5)
T_WORLD_BASE = T_from_rotvec([0.0, 0.0, 0.1], [0.2, 0.0, 0.0])
T_WORLD_TCP = look_at([0.6, 0.2, 0.6], [0.5, 0.0, 0.0])
T_TCP_CAM = T_from_rotvec([0.0, 0.0, 0.05], [0.03, 0.0, 0.05])
T_WORLD_BASEPLATE = T_from_rotvec([0.0, 0.0, 0.0], [0.5, 0.0, 0.0])
T_WORLD_LH = look_at([2.0, 1.0, 2.0], [0.5, 0.0, 0.0])
T_TCP_TRACKER = T_from_rotvec([0.0, 0.0, 0.0], [0.0, 0.05, -0.03])


def seed_004_cell(effects=None, mount=None) -> SimCell:
    """Seed 004: base plate on the table, the planar plate held by the suction gripper."""
    plate = make_workpiece("planar_plate")
    base = make_workpiece("base_plate")
    return SimCell(
        DepthCameraModel(INTRINSICS, DepthNoiseModel.noiseless()),
        mount if mount is not None else CameraMount.eye_in_hand(T_TCP_CAM),
        [
            PartPlacement("base_plate", base, T_WORLD_BASEPLATE),
            PartPlacement("plate", plate, T_from_rotvec([math.pi, 0, 0], [0, 0, 0.2]), parent="tcp"),
        ],
        effects,
        T_world_base=T_WORLD_BASE,
        tracker=TrackerMount(T_WORLD_LH, T_TCP_TRACKER, ViveTrackerModel.ideal()),
    )


def _world_poses(frames) -> dict[str, np.ndarray]:
    """Compose the frame tree from the root 'world'."""
    poses = {"world": np.eye(4)}
    pending = list(frames)
    while pending:
        progressed = False
        for f in list(pending):
            if f.parent in poses:
                poses[f.child] = poses[f.parent] @ f.T_parent_child
                pending.remove(f)
                progressed = True
        assert progressed, f"frames not connected to world: {[(f.parent, f.child) for f in pending]}"
    return poses


def test_frames_form_a_tree_that_composes_to_the_cell_poses():
    cell = seed_004_cell()
    frames = cell.frames(T_WORLD_TCP)
    names = [f.child for f in frames]
    assert names == ["base", "tcp", "camera", "base_plate", "plate", "lighthouse", "tracker"]
    assert len(set(names)) == len(names)
    poses = _world_poses(frames)
    np.testing.assert_allclose(poses["base"], T_WORLD_BASE, atol=1e-12)
    np.testing.assert_allclose(poses["tcp"], T_WORLD_TCP, atol=1e-12)
    np.testing.assert_allclose(poses["camera"], T_WORLD_TCP @ T_TCP_CAM, atol=1e-12)
    # the parts as placed in seed_004_cell: the base plate on the table, the plate held by the tool
    np.testing.assert_allclose(poses["base_plate"], T_WORLD_BASEPLATE, atol=1e-12)
    T_tcp_plate = T_from_rotvec([math.pi, 0, 0], [0, 0, 0.2])
    np.testing.assert_allclose(poses["plate"], T_WORLD_TCP @ T_tcp_plate, atol=1e-12)
    np.testing.assert_allclose(poses["tracker"], T_WORLD_TCP @ T_TCP_TRACKER, atol=1e-12)
    np.testing.assert_allclose(poses["lighthouse"], T_WORLD_LH, atol=1e-12)


def test_truth_frames_carry_the_injected_errors_and_nominal_ones_do_not():
    E_cam = PoseOffset((0.001, 0.0, 0.0), (0.0, 0.01, 0.0))
    E_plate = PoseOffset((0.0, 0.002, 0.0), (0.0, 0.0, 0.02))
    cell = seed_004_cell(SensorEffects(camera=CameraEffects(hand_eye_error=E_cam), placement={"plate": E_plate}))
    nominal = _world_poses(cell.frames(T_WORLD_TCP))
    true = _world_poses(cell.frames(T_WORLD_TCP, truth=True))
    np.testing.assert_allclose(nominal["camera"], T_WORLD_TCP @ T_TCP_CAM, atol=1e-12)
    np.testing.assert_allclose(true["camera"], T_WORLD_TCP @ T_TCP_CAM @ E_cam.matrix(), atol=1e-12)
    np.testing.assert_allclose(inv(nominal["plate"]) @ true["plate"], E_plate.matrix(), atol=1e-12)
    np.testing.assert_allclose(true["base_plate"], nominal["base_plate"], atol=1e-15)


def test_frames_follow_a_moving_robot_and_skip_what_needs_a_tcp():
    cell = seed_004_cell()
    traj = lambda t: T_from_rotvec([0, 0, 0.1 * t], [0.5 + 0.1 * t, 0.0, 0.4])  # noqa: E731
    poses = _world_poses(cell.frames(traj, t=2.0))
    np.testing.assert_allclose(poses["tcp"], traj(2.0), atol=1e-12)
    fixed = seed_004_cell(mount=CameraMount.eye_to_hand(look_at([1, 1, 1], [0.5, 0, 0])))
    names = [f.child for f in fixed.frames(None)]
    assert names == ["base", "camera", "base_plate", "lighthouse"]


def test_capture_sees_the_gripped_plate_and_labels_the_parts():
    cell = seed_004_cell(mount=CameraMount.eye_to_hand(look_at([0.5, 0.0, 0.9], [0.5, 0.0, 0.0], up=(0, 1, 0))))
    T_world_tcp = T_from_rotvec([math.pi, 0, 0], [0.5, 0.0, 0.5])  # tool down, plate 0.2 m below
    cap, truth = cell.capture(T_world_tcp, np.random.default_rng(0))
    assert truth.part_names == ["base_plate", "plate"]
    assert set(np.unique(truth.render.part_index)) == {0, 1}
    np.testing.assert_allclose(truth.T_cam_parts["plate"], inv(truth.T_world_cam) @ truth.T_world_parts["plate"])
    assert cap.stamp_ns == 0 and truth.T_world_tcp is not None


def test_assembled_pose_through_the_cell():
    """Holding the plate so it sits at assembled_plate_pose() puts its pins on the base holes."""
    cell = seed_004_cell()
    plate_in_tcp = cell.parts[1].T_parent_part
    T_world_plate = T_WORLD_BASEPLATE @ assembled_plate_pose()
    T_world_tcp = T_world_plate @ inv(plate_in_tcp)
    T = cell.part_pose(cell.parts[1], T_world_tcp, truth=False)
    plate, base = cell.parts[1].workpiece, cell.parts[0].workpiece
    for i in (1, 2):
        pin = T @ np.append(plate.features[f"pin{i}"], 1.0)
        hole = T_WORLD_BASEPLATE @ np.append(base.features[f"hole{i}"], 1.0)
        np.testing.assert_allclose(pin, hole, atol=1e-12)


def test_tracker_follows_the_tcp_with_the_cell_effects():
    cell = seed_004_cell(SensorEffects(tracker=TrackerEffects(latency_s=0.01)))
    traj = lambda t: T_from_rotvec([0, 0, 0], [0.5 + 0.2 * t, 0.0, 0.4])  # noqa: E731
    sample, _ = cell.tracker(traj).sample(1.0, np.random.default_rng(0))
    expected = inv(T_WORLD_LH) @ traj(0.99) @ T_TCP_TRACKER
    np.testing.assert_allclose(sample.T_lighthouse_tracker, expected, atol=1e-12)
    ideal, _ = cell.tracker(traj, with_effects=False).sample(1.0, np.random.default_rng(0))
    np.testing.assert_allclose(ideal.T_lighthouse_tracker, inv(T_WORLD_LH) @ traj(1.0) @ T_TCP_TRACKER, atol=1e-12)


def test_bad_cell_input_is_refused():
    plate = make_workpiece("planar_plate")
    cam = DepthCameraModel(INTRINSICS)
    with pytest.raises(ValueError, match="unique"):
        SimCell(cam, CameraMount.eye_in_hand(np.eye(4)), [PartPlacement("p", plate, np.eye(4))] * 2)
    with pytest.raises(ValueError, match="parent"):
        PartPlacement("p", plate, np.eye(4), parent="table")
    with pytest.raises(ValueError, match="kind"):
        CameraMount("on_the_wall", np.eye(4))
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match="not a rotation"):
        CameraMount.eye_in_hand(bad)
    with pytest.raises(ValueError, match="not a rotation"):
        PartPlacement("p", plate, bad)
    cell = SimCell(cam, CameraMount.eye_in_hand(T_TCP_CAM), [PartPlacement("p", plate, np.eye(4))])
    with pytest.raises(ValueError, match="TCP pose"):
        cell.capture(None, np.random.default_rng(0))
    with pytest.raises(ValueError, match="no tracker"):
        cell.tracker(lambda t: np.eye(4))
    with pytest.raises(ValueError, match="finite"):
        cell.capture(T_WORLD_TCP, np.random.default_rng(0), t=float("inf"))
    with pytest.raises(ValueError, match="no parts"):
        SimCell(cam, CameraMount.eye_to_hand(T_WORLD_TCP), []).capture(None, np.random.default_rng(0))
