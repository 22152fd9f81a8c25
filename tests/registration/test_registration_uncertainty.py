"""The pose uncertainty: the formula right where its model holds, the reported sigma calibrated on
simulated captures (held-out from the captures the factor was measured on), and weak directions
flagged (a flat plate slides in its plane)."""

from __future__ import annotations

import numpy as np
import pytest
import registration_scenes as scenes

from engine import transforms as tf
from plugins.registration import (
    FineParams,
    GlobalParams,
    PreprocessParams,
    RoiBox,
    prepare_cloud,
    register_fine,
    register_global,
)


def _error_z(res, T_true: np.ndarray) -> np.ndarray:
    """Estimation error as a twist at the uncertainty centre, in units of the reported sigmas."""
    xi_origin = tf.log_se3(res.T_match @ tf.inv(T_true))  # T_est = exp(xi) T_true
    xi_center = tf.adjoint(tf.inv(tf.T_from_Rt(np.eye(3), res.uncertainty_center))) @ xi_origin
    return xi_center / np.concatenate([res.sigma_translation_m, res.sigma_rotation_rad])


def _faceted_surface() -> np.ndarray:
    """Three faces of a 6 cm box and an oblique face, on a 3 mm grid, 0.5 m from the camera."""
    u = np.linspace(0.0, 0.06, 20)
    U, V = (a.ravel() for a in np.meshgrid(u, u))
    Z = np.zeros_like(U)
    faces = [np.c_[U, V, Z], np.c_[U, Z, V], np.c_[Z, U, V], np.c_[U, V, 0.06 - 0.5 * U + 0.2 * V]]
    return np.vstack(faces) + np.array([0.0, 0.0, 0.5])


@pytest.mark.parametrize("cluster_factor", [0.0, 5.0])
def test_covariance_is_calibrated_when_its_model_holds(cluster_factor):
    """Monte Carlo: i.i.d. Gaussian noise along the normals of a noiseless template, point-to-plane ICP,
    no calibration factor (sigma_scale 1). The errors divided by the reported sigmas must have unit
    RMS on every axis, with the i.i.d. formula (cluster factor 0) and with the cluster-robust one
    vgr reports by default (which must not overstate the error where residuals are independent)."""
    P = _faceted_surface()
    pp = PreprocessParams(voxel_size_m=0.0, normal_k=12)
    template = prepare_cloud(P, pp)
    normals = template.normals()
    params = FineParams(
        backend="open3d_plane",
        preprocess=pp,
        max_correspondence_m=0.01,
        sigma_scale=1.0,
        sigma_cluster_factor=cluster_factor,
    )
    rng = np.random.default_rng(7)
    T_c = tf.T_from_Rt(np.eye(3), P.mean(axis=0))
    z = []
    for _ in range(150):
        T_true = T_c @ tf.exp_se3(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 0.01, 3)]) @ tf.inv(T_c)
        current = tf.transform_points(tf.inv(T_true), P + normals * rng.normal(0.0, 2e-4, (len(P), 1)))
        res = register_fine(current, template, None, params)
        assert res.verdict == "ok", res.summary()
        z.append(_error_z(res, T_true))
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    assert np.all((rms > 0.8) & (rms < 1.25)), rms


def _feature_part_errors(rng, n: int, near: bool) -> list[np.ndarray]:
    cam = scenes.camera(1280, 960)
    z = []
    for _ in range(n):
        tmpl = scenes.capture("feature_part", scenes.nominal_pose("feature_part"), cam, rng)
        if near:  # as guidance's later looks: 2 mm / 1 deg from the template pose
            pose = scenes.perturbed_pose("feature_part", rng, max_shift_m=0.002, max_tilt_deg=1, spin_deg=1)
        else:
            pose = scenes.perturbed_pose("feature_part", rng, max_shift_m=0.02, max_tilt_deg=10, spin_deg=20)
        cur = scenes.capture("feature_part", pose, cam, rng)
        T_true = scenes.true_match(tmpl, cur)
        T0 = tf.exp_se3(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, np.radians(0.5), 3)]) @ T_true
        res = register_fine(cur.points, tmpl.points, T0, FineParams())
        assert res.verdict == "ok", res.summary()
        z.append(_error_z(res, T_true))
    return z


def _plate_errors(rng, n: int) -> list[np.ndarray]:
    """planar_plate from above, captured template, global matcher (planar sweep + contour edges)."""
    cam = scenes.camera(640, 480)
    z = []
    for _ in range(n):
        tmpl, cur = scenes.capture_pair("planar_plate", cam, rng, max_shift_m=0.02, max_tilt_deg=0, spin_deg=10)
        res = register_global(cur.points, prepare_cloud(tmpl.points), GlobalParams(seed=1))
        assert res.verdict == "ok" and res.method.endswith("+edges"), res.summary()
        z.append(_error_z(res, scenes.true_match(tmpl, cur)))
    return z


@pytest.mark.parametrize("case", ["feature_part", "feature_part_near", "planar_plate"])
def test_reported_sigma_is_calibrated_on_held_out_captures(case):
    """The reported one-sigma (cluster-robust covariance x FineParams.sigma_scale = 2.0) against the
    true error, per axis, on captures NOT used to measure the factor (it was measured on seeds 100
    and 200 of the same scenarios; these are seeds 3-5). Before (i.i.d. formula, no factor) the
    errors reached RMS 3.4 and 10.6 sigma. Measured here: RMS 0.2-1.3 per axis, worst 3.7 sigma.
    Not covered: systematic model errors, e.g. a CAD template against a capture (below)."""
    rng = np.random.default_rng({"feature_part": 3, "feature_part_near": 4, "planar_plate": 5}[case])
    if case == "planar_plate":
        z = _plate_errors(rng, 5)
    else:
        z = _feature_part_errors(rng, 10, near=case.endswith("near"))
    z = np.abs(np.array(z))
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all(rms <= 1.5), rms
    assert rms.max() >= 0.3, rms  # and not inflated: a sigma 3x too large would read RMS < 0.3 here
    assert z.max() <= 5.0, z.max()


#: a crop box smaller than the planes below: their borders are the crop's, not the part's, so the
#: contour (edge term) says nothing and only the surface is left
ROI_INSIDE_PLANE = PreprocessParams(roi=RoiBox.from_bounds([-0.08, -0.06, 0.45], [0.08, 0.06, 0.55]))


def _plane_grid(spacing_m: float = 0.001) -> np.ndarray:
    """A 20 x 15 cm plane 0.5 m from the camera, sampled on a regular grid as a camera samples it."""
    u, v = np.meshgrid(np.arange(-0.1, 0.1, spacing_m), np.arange(-0.075, 0.075, spacing_m))
    return np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 0.5)])


def test_flat_plate_is_flagged_weak_and_ambiguous():
    """A plain plane larger than the crop box: it can slide in its plane and spin about its normal.
    (Seen whole, a rectangle's contour fixes those: test_registration_edges.py.)"""
    rng = np.random.default_rng(0)
    P = _plane_grid()
    cur = P + np.column_stack([np.zeros((len(P), 2)), rng.normal(0.0, 1e-4, len(P))])
    res = register_fine(cur, P, None, FineParams(preprocess=ROI_INSIDE_PLANE))
    assert res.verdict == "ambiguous", res.summary()
    assert res.T_match is None and not res.usable
    kinds = sorted(w.kind for w in res.weak_directions)
    assert kinds == ["rotation", "translation", "translation"], res.weak_directions
    for w in res.weak_directions:
        if w.kind == "translation":
            assert abs(w.axis[2]) < 0.05  # sliding in the plane (x, y), not along its normal
        else:
            assert abs(w.axis[2]) > 0.99  # spinning about the normal
    assert "not determined" in res.reasons[0]
    assert res.sigma_translation_m[2] < 1e-5  # the normal direction is well determined


def test_noise_free_plane_is_still_ambiguous():
    """Zero residuals make every sigma 0; the geometry test must still refuse the plane."""
    P = _plane_grid(0.002)
    res = register_fine(P, P, None, FineParams(preprocess=ROI_INSIDE_PLANE))
    assert res.verdict == "ambiguous" and res.T_match is None, res.summary()
    assert "stiffness ratio" in res.reasons[0]


@pytest.mark.parametrize("view_tilt_deg", [0.0, 30.0])
def test_planar_plate_pins_constrain_the_plane_directions(view_tilt_deg):
    """planar_plate (CAD-model template, 640 x 480 capture): the pins and the contour walls pin down
    the in-plane directions, so the result is usable, and the in-plane sigmas are the largest.

    Seen straight from above the plate's in-plane pose comes only from the pins and from contour
    points paired with the model's walls, which 2 mm voxels can bias (measured 0.18 mm / 0.26 deg,
    about 30 reported sigmas, for a 1 mm / 0.6 deg offset: the sigma does not include such systematic
    errors; 0.09 mm / 0.05 deg for the 3.6 mm / 2.9 deg offset used here, larger than the limits so
    that a match that does nothing fails), within seed 004's 0.5 mm / 0.5 deg. An oblique view shows
    the walls and does much better (0.008 mm / 0.002 deg)."""
    cam = scenes.camera(640, 480)
    rng = np.random.default_rng(1)
    pose = scenes.nominal_pose("planar_plate", view_tilt_deg)
    tmpl = scenes.model_template("planar_plate", pose, 0.0007, rng)
    cur = scenes.capture("planar_plate", pose @ tf.T_from_rotvec([0, 0, 0.05], [0.003, -0.002, 0.0]), cam, rng)
    res = register_fine(cur.points, tmpl.points, None, FineParams(backend="open3d_plane"))
    assert res.verdict == "ok", res.summary()
    err_mm, err_deg = scenes.match_error(res.T_match, tmpl, cur, "planar_plate")
    limit = (0.5, 0.5) if view_tilt_deg == 0.0 else (0.1, 0.05)
    assert err_mm < limit[0] and err_deg < limit[1], (err_mm, err_deg)
    normal = pose[:3, 2]  # plate normal in the camera frame
    cov_t = res.covariance_at(res.uncertainty_center)[:3, :3]
    in_plane = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    sigma_normal = float(np.sqrt(normal @ cov_t @ normal))
    sigma_in_plane = np.sqrt(np.diag(in_plane.T @ cov_t @ in_plane))
    assert np.all(sigma_in_plane > 3.0 * sigma_normal), (sigma_in_plane, sigma_normal)
