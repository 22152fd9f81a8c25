"""Simulated depth camera: geometry, noise model, dropouts, range, determinism, pose recovery, bad input."""

import math

import numpy as np
import open3d as o3d
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy import stats
from simcam_helpers import error_twist, expected_covariance, fit_part_pose, on_surface_distance

from engine.transforms import T_from_rotvec, inv, transform_points
from plugins.camera.pinhole import CameraModel
from plugins.sim.camera import (
    DepthCameraModel,
    DepthNoiseModel,
    default_intrinsics,
    look_at,
)
from plugins.util.workpieces import make_workpiece

MM = 1e-3
SMALL = CameraModel.pinhole(160, 120, 138.6, 138.6, 79.5, 59.5)  # 60 deg HFOV, quick to render


def wall(size: float = 2.0, thickness: float = 0.02) -> o3d.geometry.TriangleMesh:
    """A closed slab whose front face is the plane z = 0 of its frame, facing -z (towards a camera)."""
    box = o3d.geometry.TriangleMesh.create_box(size, size, thickness)
    box.translate((-size / 2, -size / 2, 0.0))
    box.compute_triangle_normals()
    return box


def wall_pose(z: float, tilt_deg: float = 0.0) -> np.ndarray:
    """World pose of the wall: front face at depth z in a camera at the origin, tilted about y."""
    return T_from_rotvec([0.0, math.radians(tilt_deg), 0.0], [0.0, 0.0, z])


@pytest.fixture(scope="module")
def feature_part():
    return make_workpiece("feature_part")


def test_default_intrinsics():
    k = default_intrinsics()
    assert (k.width, k.height) == (640, 480)
    assert math.degrees(k.horizontal_fov_rad) == pytest.approx(60.0, abs=0.01)
    np.testing.assert_allclose(k.K, [[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1]])


def test_noiseless_points_lie_on_the_part_and_reproject_to_their_pixels(feature_part):
    cam = DepthCameraModel(default_intrinsics(), DepthNoiseModel.noiseless())
    T_world_part = T_from_rotvec([0.1, -0.05, 0.7], [0.02, -0.01, 0.0])
    T_world_cam = look_at([0.3, 0.25, 0.5], [0.0, 0.0, 0.03])
    cap, truth = cam.render_with_truth([(feature_part, T_world_part)], T_world_cam, np.random.default_rng(0))
    assert len(cap.points) > 5000
    T_cam_part = inv(T_world_cam) @ T_world_part
    np.testing.assert_allclose(truth.T_cam_parts[0], T_cam_part, atol=1e-12)
    # every valid point is on the part's surface (float32 ray casting: ~0.1 um at 0.7 m)
    assert on_surface_distance(feature_part, cap.points, T_cam_part).max() < 1e-6
    np.testing.assert_allclose(cap.points, truth.points_true, atol=1e-9)
    # the organised cloud and the depth image agree with the point list, pixel by pixel
    u, v = cap.pixels[:, 0], cap.pixels[:, 1]
    np.testing.assert_allclose(cap.organized[v, u], cap.points, atol=1e-6)
    np.testing.assert_allclose(cap.depth[v, u], cap.points[:, 2], atol=1e-6)
    assert np.count_nonzero(cap.valid_mask) == len(cap.points)
    assert np.all(np.isnan(cap.depth[~cap.valid_mask])) and np.all(np.isnan(cap.organized[~cap.valid_mask]))
    # pinhole projection of each point lands on its own pixel centre
    np.testing.assert_allclose(cap.intrinsics.project_camera_points(cap.points), cap.pixels, atol=1e-4)
    # reported normals are the true outward normals, facing the camera
    assert np.all(np.einsum("ij,ij->i", cap.normals, cap.points) < 0)
    np.testing.assert_allclose(np.linalg.norm(cap.normals, axis=1), 1.0, atol=1e-6)


def test_depth_noise_follows_the_sigma_model():
    """Range error along the ray has zero mean and sigma(z) = a + b z^2, at two depths."""
    noise = DepthNoiseModel(sigma_const_m=0.0005, sigma_quad_per_m=0.002)
    cam = DepthCameraModel(SMALL, noise, max_range_m=3.0)
    for z in (0.5, 1.5):
        cap, truth = cam.render_with_truth([(wall(), wall_pose(z))], np.eye(4), np.random.default_rng(1))
        dirs = truth.points_true / np.linalg.norm(truth.points_true, axis=1, keepdims=True)
        err = np.einsum("ij,ij->i", cap.points - truth.points_true, dirs)
        # the error is along the ray only
        np.testing.assert_allclose(cap.points - truth.points_true, err[:, None] * dirs, atol=1e-12)
        expected = 0.0005 + 0.002 * z**2
        n = len(err)
        assert n == SMALL.width * SMALL.height
        assert abs(err.mean()) < 4 * expected / math.sqrt(n)
        assert err.std() == pytest.approx(expected, rel=4 / math.sqrt(2 * n) + 0.01)
        assert stats.normaltest(err / truth.sigma_m).pvalue > 1e-3


def test_grazing_dropout_keeps_exactly_the_rays_below_the_limit():
    """On a tilted plane, a pixel is valid iff its ray meets the plane at incidence <= the limit."""
    cam = DepthCameraModel(SMALL, DepthNoiseModel(sigma_const_m=0.0, grazing_dropout_deg=70.0), max_range_m=50.0)
    k = SMALL
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    rays = np.stack(((u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones(u.shape)), axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    for tilt in (40.0, 60.0, 75.0):
        T_wall = wall_pose(1.0, tilt)
        cap = cam.render([(wall(40.0), T_wall)], np.eye(4), np.random.default_rng(0))
        normal = T_wall[:3, :3] @ np.array([0.0, 0.0, -1.0])
        incidence = np.degrees(np.arccos(-rays @ normal))
        clear = np.abs(incidence - 70.0) > 0.01  # leave out rays within float32 noise of the limit
        np.testing.assert_array_equal(cap.valid_mask[clear], incidence[clear] <= 70.0)
        assert np.count_nonzero(cap.valid_mask) > 0 or tilt > 70.0


def test_range_limits_apply_to_the_true_depth():
    cam = DepthCameraModel(SMALL, DepthNoiseModel.noiseless(), min_range_m=0.5, max_range_m=1.0)
    rng = np.random.default_rng(0)
    assert len(cam.render([(wall(), wall_pose(0.3))], np.eye(4), rng).points) == 0
    assert len(cam.render([(wall(), wall_pose(1.2))], np.eye(4), rng).points) == 0
    assert len(cam.render([(wall(), wall_pose(0.8))], np.eye(4), rng).points) == SMALL.width * SMALL.height
    # a plane through both limits is cut at exactly z = 0.5 and z = 1.0
    cap = cam.render([(wall(4.0), wall_pose(0.75, 50.0))], np.eye(4), rng)
    z = cap.points[:, 2]
    assert z.min() >= 0.5 and z.max() <= 1.0
    assert z.min() < 0.5 + 0.01 and z.max() > 1.0 - 0.01


def test_field_of_view_is_the_image(feature_part):
    """A part beside the view frustum is not seen; moved into it, it is."""
    cam = DepthCameraModel(SMALL, DepthNoiseModel.noiseless())
    half_fov = SMALL.horizontal_fov_rad / 2
    z = 0.6
    beside = T_from_rotvec([0, 0, 0], [z * math.tan(half_fov) + 0.2, 0.0, z])
    ahead = T_from_rotvec([0, 0, 0], [0.0, 0.0, z])
    rng = np.random.default_rng(0)
    assert len(cam.render([(feature_part, beside)], np.eye(4), rng).points) == 0
    assert len(cam.render([(feature_part, ahead)], np.eye(4), rng).points) > 0


def test_random_dropout_rate():
    cam = DepthCameraModel(SMALL, DepthNoiseModel(sigma_const_m=0.0, dropout_prob=0.2))
    cap = cam.render([(wall(), wall_pose(1.0))], np.eye(4), np.random.default_rng(3))
    n = SMALL.width * SMALL.height
    kept = len(cap.points) / n
    assert kept == pytest.approx(0.8, abs=4 * math.sqrt(0.16 / n))


def test_same_seed_same_frame_other_seed_other_noise(feature_part):
    cam = DepthCameraModel(SMALL, DepthNoiseModel.realsense_d415())
    T_world_cam = look_at([0.3, 0.2, 0.5], [0.0, 0.0, 0.02])
    parts = [(feature_part, np.eye(4))]
    a = cam.render(parts, T_world_cam, np.random.default_rng(11))
    b = cam.render(parts, T_world_cam, np.random.default_rng(11))
    c = cam.render(parts, T_world_cam, np.random.default_rng(12))
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(np.nan_to_num(a.depth), np.nan_to_num(c.depth))


def test_occlusion_and_part_labels(feature_part):
    """A plate in front hides the part behind it; truth labels each point with its part."""
    plate = make_workpiece("planar_plate")
    cam = DepthCameraModel(SMALL, DepthNoiseModel.noiseless())
    T_world_cam = look_at([0.0, 0.0, 0.8], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    T_plate = T_from_rotvec([0, 0, 0], [0.08, 0.0, 0.3])  # covers the +x half of the part
    cap, truth = cam.render_with_truth(
        [(feature_part, np.eye(4)), (plate, T_plate)], T_world_cam, np.random.default_rng(0)
    )
    assert set(np.unique(truth.part_index)) == {0, 1}
    world = transform_points(T_world_cam, cap.points)
    on_plate = truth.part_index == 1
    assert np.all(world[on_plate, 2] > 0.3 - 1e-6)
    # no feature_part point is seen where the plate covers it
    part_xy = world[~on_plate, :2]
    plate_xy = world[on_plate, :2]
    assert len(part_xy) > 0
    assert part_xy[:, 0].min() < -0.07  # the uncovered -x end of the part is seen
    covered = (part_xy[:, 0] > 0.0) & (part_xy[:, 0] < 0.05) & (np.abs(part_xy[:, 1]) < 0.02)
    assert not np.any(covered)
    assert np.any((plate_xy[:, 0] > 0.0) & (plate_xy[:, 0] < 0.03) & (np.abs(plate_xy[:, 1]) < 0.013))


# --------------------------------------------------------------------------- pose recovery


def _fit_case(feature_part, seed: int, intrinsics: CameraModel):
    cam = DepthCameraModel(intrinsics, DepthNoiseModel(sigma_const_m=0.0003))
    T_world_cam = look_at([0.3, 0.25, 0.55], [0.0, 0.0, 0.03])
    T_world_part = T_from_rotvec([0.05, -0.03, 0.4], [0.01, -0.02, 0.0])
    cap, truth = cam.render_with_truth([(feature_part, T_world_part)], T_world_cam, np.random.default_rng(seed))
    T_true = truth.T_cam_parts[0]
    T_init = T_from_rotvec([0.02, -0.01, 0.03], [0.003, -0.002, 0.002]) @ T_true  # ~2 deg, ~4 mm off
    T_est = fit_part_pose(cap.points, feature_part, T_init)
    return error_twist(T_est, T_true), expected_covariance(cap, truth), len(cap.points)


def test_fit_recovers_the_pose_within_the_noise_expectation(feature_part):
    """ICP of the rendered cloud to the mesh lands within 4 predicted sigma (plus a 10 um floor).

    The prediction is the covariance of point-to-plane least squares under the noise model
    (sigma = 0.3 mm along each ray); a noiseless render fits to ~8 um, which is the floor.
    """
    xi, cov, n = _fit_case(feature_part, seed=0, intrinsics=default_intrinsics())
    assert n > 8000
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(xi[:3]) < 4 * sd[:3] + 10e-6), (xi[:3] / MM, sd[:3] / MM)
    assert np.all(np.abs(xi[3:]) < 4 * sd[3:] + math.radians(0.001)), (np.degrees(xi[3:]), np.degrees(sd[3:]))
    # and the result is sub-0.2 mm / sub-0.02 deg, so it is no loose bound either
    assert np.linalg.norm(xi[:3]) < 0.2 * MM and np.degrees(np.linalg.norm(xi[3:])) < 0.02


@pytest.mark.slow
def test_fit_errors_match_the_predicted_covariance_over_seeds(feature_part):
    """Monte Carlo (12 seeds): the mean squared Mahalanobis error is chi^2(6)-like (mean 6).

    Observed ~8 (ICP edge correspondences add a little to the least-squares ideal); the bounds
    fail both for a noise model that is not applied and for one applied twice as large.
    """
    m2 = []
    for seed in range(12):
        xi, cov, _ = _fit_case(
            feature_part, seed=100 + seed, intrinsics=CameraModel.pinhole(320, 240, 277.1, 277.1, 159.5, 119.5)
        )
        m2.append(float(xi @ np.linalg.solve(cov, xi)))
    assert 3.0 < np.mean(m2) < 14.0, m2


# --------------------------------------------------------------------------- depth effects


def test_depth_scale_error_grows_linearly_with_depth():
    scale = 1.004
    cam = DepthCameraModel(SMALL, DepthNoiseModel(sigma_const_m=0.0, depth_scale=scale), max_range_m=3.0)
    rng = np.random.default_rng(0)
    z_true, z_err = [], []
    for z in (0.4, 0.8, 1.6, 2.4):
        cap, truth = cam.render_with_truth([(wall(4.0), wall_pose(z, 30.0))], np.eye(4), rng)
        z_true.append(truth.points_true[:, 2])
        z_err.append(cap.points[:, 2] - truth.points_true[:, 2])
    z_true, z_err = np.concatenate(z_true), np.concatenate(z_err)
    slope, intercept = np.polyfit(z_true, z_err, 1)
    assert slope == pytest.approx(scale - 1.0, rel=1e-4)
    assert abs(intercept) < 1e-7
    assert z_err.max() == pytest.approx((scale - 1.0) * z_true.max(), rel=1e-4)  # 9.6 mm at 2.4 m


def test_depth_bias_is_a_constant_shift_along_each_ray(feature_part):
    bias = 0.002
    cam = DepthCameraModel(SMALL, DepthNoiseModel(sigma_const_m=0.0, depth_bias_m=bias))
    T_world_cam = look_at([0.3, 0.2, 0.5], [0.0, 0.0, 0.02])
    cap, truth = cam.render_with_truth([(feature_part, np.eye(4))], T_world_cam, np.random.default_rng(0))
    dirs = truth.points_true / np.linalg.norm(truth.points_true, axis=1, keepdims=True)
    np.testing.assert_allclose(cap.points - truth.points_true, bias * dirs, atol=1e-9)
    # off-axis rays: the z shift is bias * cos(angle to the axis), not a constant z offset
    assert np.ptp(cap.points[:, 2] - truth.points_true[:, 2]) > 1e-5


def test_effects_are_off_by_default():
    noise = DepthNoiseModel()
    assert noise.depth_scale == 1.0 and noise.depth_bias_m == 0.0 and noise.dropout_prob == 0.0


# --------------------------------------------------------------------------- bad input


def test_empty_scene_and_bad_parts_fail_clearly(feature_part):
    cam = DepthCameraModel(SMALL)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="no parts"):
        cam.render([], np.eye(4), rng)
    with pytest.raises(ValueError, match="empty mesh"):
        cam.render([(o3d.geometry.TriangleMesh(), np.eye(4))], np.eye(4), rng)
    with pytest.raises(TypeError, match="TriangleMesh or a Workpiece"):
        cam.render([("feature_part", np.eye(4))], np.eye(4), rng)
    with pytest.raises(TypeError, match="pair"):
        cam.render([feature_part], np.eye(4), rng)
    with pytest.raises(TypeError, match="Generator"):
        cam.render([(feature_part, np.eye(4))], np.eye(4), 42)
    broken = o3d.geometry.TriangleMesh(feature_part.mesh)
    vertices = np.asarray(broken.vertices)
    vertices[3] = np.nan
    with pytest.raises(ValueError, match="NaN or infinite vertices"):
        cam.render([(broken, np.eye(4))], np.eye(4), rng)


def test_camera_inside_a_part_fails_clearly(feature_part):
    cam = DepthCameraModel(SMALL)
    inside = T_from_rotvec([0, 0, 0], [-0.03, 0.0, 0.01])  # in the slab of the part
    with pytest.raises(ValueError, match="inside a part"):
        cam.render([(feature_part, np.eye(4))], inside, np.random.default_rng(0))


def test_inward_facing_mesh_is_refused_and_a_few_back_faces_are_dropped():
    cam = DepthCameraModel(SMALL, DepthNoiseModel.noiseless())
    rng = np.random.default_rng(0)
    inverted = wall()
    inverted.triangles = o3d.utility.Vector3iVector(np.asarray(inverted.triangles)[:, ::-1].copy())
    # the occupancy test sees no inside (parity of crossings), the back faces give it away
    with pytest.raises(ValueError, match="inward-facing"):
        cam.render([(inverted, wall_pose(1.0))], np.eye(4), rng)
    # one flipped triangle among many: only its pixels are lost
    tiles = o3d.geometry.TriangleMesh.create_box(2.0, 2.0, 0.02).subdivide_midpoint(4)
    tiles.translate((-1.0, -1.0, 0.0))
    F = np.asarray(tiles.triangles).copy()
    centres = np.asarray(tiles.vertices)[F].mean(axis=1)
    front = np.flatnonzero(centres[:, 2] < 1e-9)
    flip = front[np.argmin(np.linalg.norm(centres[front, :2], axis=1))]  # the front tile on the axis
    F[flip] = F[flip, ::-1]
    tiles.triangles = o3d.utility.Vector3iVector(F)
    cap = cam.render([(tiles, wall_pose(1.0))], np.eye(4), rng)
    lost = SMALL.width * SMALL.height - len(cap.points)
    assert 0 < lost < 0.05 * SMALL.width * SMALL.height
    u, v = np.rint(SMALL.project_camera_points(centres[flip] + [0.0, 0.0, 1.0])[0]).astype(int)
    assert not cap.valid_mask[v, u]  # the flipped triangle's centre pixel is among the lost ones


def _scaled(T: np.ndarray, s: float) -> np.ndarray:
    T = T.copy()
    T[:3, :3] *= s
    return T


@settings(max_examples=30, deadline=None)
@given(
    st.sampled_from(["scale", "shear", "nan", "last_row", "shape"]),
    st.floats(0.05, 0.5),
    st.booleans(),
)
def test_non_rigid_poses_are_refused(kind, amount, on_camera):
    cam = DepthCameraModel(SMALL)
    good = look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    bad = good.copy()
    if kind == "scale":
        bad = _scaled(good, 1.0 + amount)
    elif kind == "shear":
        bad[0, 1] += amount
    elif kind == "nan":
        bad[1, 3] = np.nan
    elif kind == "last_row":
        bad[3, 0] = amount
    else:
        bad = good[:3]
    part = (wall(0.2), np.eye(4) if on_camera else bad)
    T_world_cam = bad if on_camera else good
    with pytest.raises(ValueError, match="T_world_cam" if on_camera else "T_world_part"):
        cam.render([part], T_world_cam, np.random.default_rng(0))


@settings(max_examples=40, deadline=None)
@given(
    st.integers(-5, 5),
    st.integers(-5, 5),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
)
def test_bad_intrinsics_are_refused(width, height, f):
    valid = width > 0 and height > 0 and math.isfinite(f) and f > 0
    if valid:
        assert CameraModel.pinhole(width, height, f, f, 0.0, 0.0).K[0, 0] == f
    else:
        with pytest.raises(ValueError):
            CameraModel.pinhole(width, height, f, f, 0.0, 0.0)


def test_zero_size_image_and_bad_noise_or_range_are_refused():
    with pytest.raises(ValueError, match="positive"):
        CameraModel.pinhole(0, 480, 500.0, 500.0, 320.0, 240.0)
    with pytest.raises(ValueError, match="integral"):
        CameraModel.pinhole(640.5, 480, 500.0, 500.0, 320.0, 240.0)
    for bad in (
        dict(sigma_const_m=-1e-3),
        dict(sigma_quad_per_m=float("nan")),
        dict(grazing_dropout_deg=0.0),
        dict(dropout_prob=1.0),
        dict(depth_scale=0.0),
        dict(depth_bias_m=float("inf")),
    ):
        with pytest.raises(ValueError):
            DepthNoiseModel(**bad)
    with pytest.raises(ValueError, match="min_range_m < max_range_m"):
        DepthCameraModel(SMALL, min_range_m=1.0, max_range_m=0.5)


def test_a_huge_negative_bias_drops_points_instead_of_flipping_them():
    cam = DepthCameraModel(SMALL, DepthNoiseModel(sigma_const_m=0.0, depth_bias_m=-2.0), max_range_m=3.0)
    cap = cam.render([(wall(), wall_pose(1.0))], np.eye(4), np.random.default_rng(0))
    assert len(cap.points) == 0 and np.all(np.isnan(cap.depth))


@settings(max_examples=15, deadline=None)
@given(
    st.tuples(*[st.floats(-math.pi, math.pi)] * 3),
    st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(0.3, 1.5)),
    st.sampled_from(["feature_part", "planar_plate", "base_plate"]),
)
# A ray that lands 1e-7 m from a face next to an edge (float32 closest-facet query named the neighbour).
@example((1.8636887822711996, 1.192092896e-07, 1.8636887822711996), (0.0, -0.03713395712849618, 1.05), "feature_part")
def test_any_pose_renders_finite_points_on_the_surface_within_range(rotvec, position, name):
    """Property: for any part pose in front of the camera, the noiseless cloud is finite, in range,
    on the part (< 1 um), and every point reprojects onto its own pixel."""
    wp = make_workpiece(name)
    cam = DepthCameraModel(SMALL, DepthNoiseModel.noiseless(), min_range_m=0.2, max_range_m=2.0)
    T_cam_part = T_from_rotvec(rotvec, position)
    cap = cam.render([(wp, T_cam_part)], np.eye(4), np.random.default_rng(0))
    assert np.all(np.isfinite(cap.points)) and np.all(np.isfinite(cap.normals))
    if len(cap.points) == 0:
        return
    assert cap.points[:, 2].min() >= 0.2 and cap.points[:, 2].max() <= 2.0
    assert on_surface_distance(wp, cap.points, T_cam_part).max() < 1e-6
    np.testing.assert_allclose(SMALL.project_camera_points(cap.points), cap.pixels, atol=1e-3)


def test_depth_units_round_the_reported_z_along_the_ray():
    """A sensor reporting 0.1 mm depth units: every z is a multiple of the unit, each point stays on
    its ray, and the rounding adds a uniform error of sigma unit/sqrt(12) to the noiseless depth."""
    unit = 1e-4
    noise = DepthNoiseModel(sigma_const_m=0.0, grazing_dropout_deg=89.9, depth_unit_m=unit)
    cam = DepthCameraModel(SMALL, noise, max_range_m=3.0)
    cap, truth = cam.render_with_truth([(wall(), wall_pose(1.0, tilt_deg=30.0))], np.eye(4), np.random.default_rng(0))
    z = cap.points[:, 2]
    np.testing.assert_allclose(z / unit, np.round(z / unit), atol=1e-6)
    np.testing.assert_allclose(
        SMALL.project_camera_points(cap.points), cap.pixels, atol=1e-3
    )  # as the other projection tests
    err = z - truth.z_true
    assert np.abs(err).max() <= unit / 2 + 1e-12
    assert np.std(err) == pytest.approx(unit / np.sqrt(12), rel=0.1)
    with pytest.raises(ValueError, match="depth_unit_m"):
        DepthNoiseModel(depth_unit_m=-1e-4)
