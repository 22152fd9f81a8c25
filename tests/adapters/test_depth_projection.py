"""Depth deprojection: exact on a synthetic plane, pixel-consistent, librealsense-equal distortion."""

from __future__ import annotations

import numpy as np
import pytest
from depth_scenes import INTR, plane_depth, plane_residual_m
from hypothesis import given, settings
from hypothesis import strategies as st

from plugins.camera.depth_projection import deproject_depth, normalized_rays, valid_points
from plugins.camera.pinhole import CameraModel

D415_COLOR = (0.1396, -0.4697, 0.0012, 0.0009, 0.4117)  # typical magnitudes of a RealSense colour camera


def rs_project(intr: CameraModel, p: np.ndarray) -> np.ndarray:
    """rsutil.h rs2_project_point_to_pixel (forward model, both Brown-Conrady variants), vectorised."""
    x, y = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
    if intr.distorted:
        k1, k2, p1, p2, k3 = intr.D
        r2 = x * x + y * y
        f = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
        if intr.model == "inverse_brown_conrady":
            x, y = x * f, y * f
            dx = x + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = y + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
        else:
            dx = x * f + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = y * f + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
        x, y = dx, dy
    return np.stack([x * intr.fx + intr.cx, y * intr.fy + intr.cy], axis=-1)


def test_plane_depth_deprojects_onto_the_plane_and_back_onto_the_pixel_grid():
    depth = plane_depth()
    pts = deproject_depth(depth, INTR)
    assert pts.shape == (60, 80, 3) and pts.dtype == np.float32
    assert plane_residual_m(pts.reshape(-1, 3)).max() < 1e-6  # float32 storage only
    uv = rs_project(INTR, pts.astype(float))
    vv, uu = np.mgrid[0:60, 0:80]
    assert np.abs(uv[..., 0] - uu).max() < 1e-4 and np.abs(uv[..., 1] - vv).max() < 1e-4
    np.testing.assert_allclose(pts[..., 2], depth, rtol=1e-6)


def test_invalid_depth_gives_nan_points_and_keeps_the_organised_layout():
    depth = plane_depth()
    depth[5, 7], depth[10, :], depth[0, 0] = 0.0, np.nan, -1.0
    pts = deproject_depth(depth, INTR)
    assert np.isnan(pts[5, 7]).all() and np.isnan(pts[10]).all() and np.isnan(pts[0, 0]).all()
    assert len(valid_points(pts)) == 60 * 80 - 80 - 2
    assert np.isfinite(valid_points(pts)).all()


@pytest.mark.parametrize("model", ["standard", "inverse_brown_conrady"])
def test_distorted_deprojection_inverts_the_librealsense_projection(model):
    intr = CameraModel.pinhole(640, 480, 615.0, 615.5, 321.1, 238.7, D415_COLOR, model)
    rays = normalized_rays(intr)
    pts = np.concatenate([rays, np.ones((*rays.shape[:2], 1))], axis=-1)
    uv = rs_project(intr, pts)
    vv, uu = np.mgrid[0:480, 0:640]
    err = np.hypot(uv[..., 0] - uu, uv[..., 1] - vv)
    assert err.max() < 1e-6  # the 10 fixed iterations converge (pixels) for camera-like coefficients


@pytest.mark.parametrize(
    "rs_model,coeffs", [("brown_conrady", D415_COLOR), ("inverse_brown_conrady", D415_COLOR), ("none", (0,) * 5)]
)
def test_deprojection_equals_librealsense_rs2_deproject_pixel_to_point(rs_model, coeffs):
    rs = pytest.importorskip("pyrealsense2")
    model = "inverse_brown_conrady" if rs_model == "inverse_brown_conrady" else "standard"
    intr = CameraModel.pinhole(640, 480, 615.0, 615.5, 321.1, 238.7, coeffs, model)
    ri = rs.intrinsics()
    ri.width, ri.height, ri.fx, ri.fy, ri.ppx, ri.ppy = 640, 480, intr.fx, intr.fy, intr.cx, intr.cy
    ri.model = getattr(rs.distortion, rs_model)
    ri.coeffs = list(coeffs)
    depth = np.full((480, 640), 0.8)
    ours = deproject_depth(depth, intr)
    rng = np.random.default_rng(3)
    for u, v in zip(rng.integers(0, 640, 200), rng.integers(0, 480, 200), strict=True):
        theirs = rs.rs2_deproject_pixel_to_point(ri, [float(u), float(v)], 0.8)
        np.testing.assert_allclose(ours[v, u], theirs, atol=1e-6)  # librealsense computes in float32


@settings(max_examples=50, deadline=None)
@given(
    f=st.floats(100.0, 2000.0),
    c=st.tuples(st.floats(0.0, 63.0), st.floats(0.0, 47.0)),
    z=st.floats(0.05, 10.0),
)
def test_constant_depth_points_have_that_depth_and_reproject(f, c, z):
    intr = CameraModel.pinhole(64, 48, f, f * 1.01, c[0], c[1])
    pts = deproject_depth(np.full((48, 64), z), intr).astype(float)
    np.testing.assert_allclose(pts[..., 2], z, rtol=1e-6)
    uv = rs_project(intr, pts)
    assert np.abs(uv[..., 0] - np.arange(64)).max() < 1e-3
    assert np.abs(uv[..., 1] - np.arange(48)[:, None]).max() < 1e-3  # (fy, cy: rows too)


def test_bad_intrinsics_and_shapes_are_refused_with_a_reason():
    with pytest.raises(ValueError, match=r"unknown distortion model 'kannala_brandt4'"):
        CameraModel.pinhole(64, 48, 50, 50, 32, 24, (), "kannala_brandt4")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="focal lengths must be positive"):
        CameraModel.pinhole(64, 48, 0.0, 50, 32, 24)
    with pytest.raises(ValueError, match="intrinsics must be finite"):
        CameraModel.pinhole(64, 48, 50, 50, float("nan"), 24)
    with pytest.raises(ValueError, match=r"K must be \[\[fx, 0, cx\]"):
        CameraModel(64, 48, np.array([[50, 1, 32], [0, 50, 24], [0, 0, 1]]), np.zeros(5))
    with pytest.raises(ValueError, match=r"\(64, 48\).*80x60"):
        deproject_depth(np.ones((48, 64)), INTR)


@pytest.mark.parametrize(
    "model,D",
    [("rational", (0.12, -0.3, 0.001, -0.0008, 0.1, 0.02, -0.05, 0.03)), ("fisheye", (0.05, -0.01, 0.003, -0.001))],
)
def test_opencv_models_deproject_onto_rays_that_project_back_onto_their_pixels(model, D):
    camera = CameraModel.pinhole(64, 48, 55.0, 55.5, 31.7, 23.2, D, model)
    pts = deproject_depth(np.full((48, 64), 0.7), camera).astype(float)
    np.testing.assert_allclose(pts[..., 2], 0.7)
    uv = camera.project(np.eye(4), pts.reshape(-1, 3)).reshape(48, 64, 2)
    vv, uu = np.mgrid[0:48, 0:64]
    assert np.abs(uv[..., 0] - uu).max() < 1e-4 and np.abs(uv[..., 1] - vv).max() < 1e-4


def test_inverse_brown_conrady_deprojects_but_does_not_project():
    camera = CameraModel.pinhole(64, 48, 55.0, 55.0, 31.5, 23.5, D415_COLOR, "inverse_brown_conrady")
    rays = normalized_rays(camera)
    np.testing.assert_allclose(camera.normalised([[10.0, 7.0]]), rays[7, 10][None], atol=1e-12)
    with pytest.raises(ValueError, match="inverse_brown_conrady"):
        camera.project(np.eye(4), [[0.0, 0.0, 1.0]])
