"""Fine registration on simulated captures with ground truth (plugins.sim): feature_part, 0.1 mm depth
noise, template and current both captured (seed 000 method A), initial guess off by ~2 mm / 1.5 deg.

Errors are the displacement of the part centre and the rotation angle between estimate and truth.
"""

from __future__ import annotations

import numpy as np
import pytest
import registration_scenes as scenes

from engine import transforms as tf
from plugins.registration import FineParams, prepare_cloud, register_fine

PART = "feature_part"


def _pairs(cam, n: int, seed: int):
    rng = np.random.default_rng(seed)
    tmpl = scenes.capture(PART, scenes.nominal_pose(PART), cam, rng)
    for _ in range(n):
        pose = scenes.perturbed_pose(PART, rng, max_shift_m=0.02, max_tilt_deg=10, spin_deg=20)
        cur = scenes.capture(PART, pose, cam, rng)
        T0 = tf.exp_se3(np.r_[rng.normal(0, 2e-3, 3), rng.normal(0, np.radians(1.5), 3)]) @ scenes.true_match(tmpl, cur)
        yield tmpl, cur, T0


def test_fine_icp_reaches_0_02_mm_and_0_005_deg_at_0_1_mm_noise():
    """The issue's accuracy target. A 5 MP capture (2448 x 2048, seed 004's sensor class, ~240k points
    on the part) and vgr's fine stage in its accuracy configuration: GICP on 2 mm voxels, then a
    polish on every point. (On 2 mm voxels alone the rotation about the optical axis is only
    determined to ~0.01 deg one sigma: see the next test and docs/registration.md.)"""
    cam = scenes.camera(2448, 2048)
    params = FineParams(polish_voxel_m=0.0, polish_correspondence_m=0.002)
    errors = []
    for tmpl, cur, T0 in _pairs(cam, 3, seed=1):
        res = register_fine(cur.points, tmpl.points, T0, params)
        assert res.verdict == "ok", res.summary()
        errors.append(scenes.match_error(res.T_match, tmpl, cur, PART))
    errors = np.array(errors)
    assert errors[:, 0].max() <= 0.02 and errors[:, 1].max() <= 0.005, errors


def test_fine_icp_on_2mm_voxels_at_the_benchmark_resolution():
    """1280 x 960 (~65k points on the part, the benchmark's clouds), 2 mm voxels, vgr's defaults:
    errors stay within 0.06 mm / 0.035 deg (the rotation is at its information limit here)."""
    cam = scenes.camera(1280, 960)
    errors = []
    for tmpl, cur, T0 in _pairs(cam, 6, seed=2):
        res = register_fine(cur.points, tmpl.points, T0, FineParams())
        assert res.verdict == "ok", res.summary()
        errors.append(scenes.match_error(res.T_match, tmpl, cur, PART))
    errors = np.array(errors)
    assert errors[:, 0].max() <= 0.06 and errors[:, 1].max() <= 0.035, errors


@pytest.mark.parametrize(
    ("backend", "limits"),
    [
        ("small_gicp_gicp", (0.06, 0.035)),
        ("open3d_gicp", (0.06, 0.035)),
        ("open3d_plane", (3.0, 1.5)),
        ("small_gicp_plane", (3.0, 1.5)),
        ("kiss_icp", (3.0, 1.5)),
    ],
)
def test_every_backend_converges_or_says_it_failed(backend, limits):
    """Each backend from a 2 mm / 1.5 deg initial error: GICP (small_gicp, Open3D) to 0.06 mm /
    0.035 deg; the others reach the neighbourhood (3 mm / 1.5 deg) or refuse (``failed``, or
    ``ambiguous``: the cluster-robust sigma of a pose stuck in a wrong minimum exceeds the limits,
    0.3-0.8 mm measured). Measured: Open3D point-to-plane sometimes stops in a neighbouring minimum
    1-2 mm away with 10 mm correspondences on this stepped part, small_gicp's point-to-plane keeps a
    0.05-0.2 mm bias on 2 mm voxels and occasionally diverges (then fails on fitness), KISS-ICP
    (point-to-point) keeps a 0.2-2 mm sampling bias. vgr's default backend is therefore small_gicp GICP."""
    cam = scenes.camera(1280, 960)
    errors, verdicts = [], []
    for tmpl, cur, T0 in _pairs(cam, 3, seed=4):
        res = register_fine(cur.points, tmpl.points, T0, FineParams(backend=backend))
        verdicts.append(res.verdict)
        if res.verdict == "ok":
            errors.append(scenes.match_error(res.T_match, tmpl, cur, PART))
        else:
            assert res.verdict in ("failed", "ambiguous") and res.reasons and res.T_match is None, res.summary()
    if backend.endswith("_gicp"):
        assert verdicts == ["ok"] * 3
    errors = np.array(errors).reshape(-1, 2)
    assert np.all(errors[:, 0] <= limits[0]) and np.all(errors[:, 1] <= limits[1]), errors


def test_prepared_template_is_reused_and_gives_the_same_answer():
    cam = scenes.camera(640, 480)
    tmpl, cur, T0 = next(_pairs(cam, 1, seed=5))
    prepared = prepare_cloud(tmpl.points)
    a = register_fine(cur.points, tmpl.points, T0)
    b = register_fine(cur.points, prepared, T0)
    c = register_fine(cur.points, prepared, T0)
    assert a.verdict == b.verdict == c.verdict == "ok"
    assert np.array_equal(a.T_match, b.T_match) and np.array_equal(b.T_match, c.T_match)
    assert "small_gicp" in prepared._cache  # built once, kept on the prepared template
