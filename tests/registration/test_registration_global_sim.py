"""Global registration on simulated captures: seed 004's table (planar plate), the truly symmetric
plate (must be reported ambiguous), and the feature-rich part from any rotation about its normal.

Seed 004 set-up: the template is generated from the part's CAD model (surface samples of the side a
sensor can see) at the template pose; the current cloud is a 0.1 mm-noise capture of the plate held
at a random pose (any rotation about its normal, tilt <= 20 deg, shift <= 40 mm). Success = final
error < 0.5 mm and < 0.5 deg at the part centre, with verdict ``ok``.
"""

from __future__ import annotations

import numpy as np
import pytest
import registration_peers as peers
import registration_scenes as scenes

from plugins.registration import FineParams, GlobalParams, prepare_cloud, register_global

#: vgr's settings for planar parts against a CAD-model template: point-to-plane for the coarse and
#: the fine ICP (the model's walls give the plate's contour points an in-plane constraint that
#: GICP's blended covariances lose), 5 deg sweep as in the paper.
PLANAR = GlobalParams(method="planar", fine=FineParams(backend="open3d_plane"), coarse_backend="open3d_plane", seed=0)


def _success(err: tuple[float, float]) -> bool:
    return err[0] < 0.5 and err[1] < 0.5


def plate_captures(part: str, seed: int, n: int):
    """Seed 004's set-up for *part*: the CAD-model template, then *n* captures at random poses, each
    registered with PLANAR; yields (result, template capture, current capture)."""
    cam = scenes.camera(640, 480)
    rng = np.random.default_rng(seed)
    tmpl = scenes.model_template(part, scenes.nominal_pose(part), 0.0007, rng)
    template = prepare_cloud(tmpl.points, PLANAR.fine.preprocess)
    for _ in range(n):
        pose = scenes.perturbed_pose(part, rng, max_shift_m=0.04, max_tilt_deg=20, spin_deg=None)
        cur = scenes.capture(part, pose, cam, rng)
        yield register_global(cur.points, template, PLANAR), tmpl, cur


@pytest.mark.slow
def test_seed_004_table_planar_plate_40_poses():
    """(a) FPFH + RANSAC + ICP (Open3D) vs (b) vgr's planar-corrected method, same 40 captures.
    Paper: (a) 25 %, (b) 100 %. vgr must reach 100 % and beat (a); the 200-pose version is in
    benchmarks/registration.py."""
    ok_vgr = ok_base = 0
    for k, (res, tmpl, cur) in enumerate(plate_captures("planar_plate", 404, 40)):
        if res.verdict == "ok" and _success(scenes.match_error(res.T_match, tmpl, cur, "planar_plate")):
            ok_vgr += 1
        T_base = peers.paper_baseline(cur.points, tmpl.points, coarse_voxel=0.004, seed=k)
        ok_base += _success(scenes.match_error(T_base, tmpl, cur, "planar_plate"))
    assert ok_vgr == 40, f"vgr planar: {ok_vgr}/40"
    assert ok_base < ok_vgr, f"FPFH+RANSAC+ICP: {ok_base}/40"


def test_symmetric_plate_is_reported_ambiguous_with_the_truth_among_the_candidates():
    for res, tmpl, cur in plate_captures("symmetric_plate", 5, 6):
        assert res.verdict == "ambiguous", res.summary()
        assert res.T_match is None and not res.usable
        assert res.score_gap < PLANAR.ambiguity_gap
        assert "symmetric" in res.reasons[0]
        top_two = [scenes.match_error(h.T_match, tmpl, cur, "symmetric_plate") for h in res.hypotheses[:2]]
        assert any(_success(e) for e in top_two), top_two
        # and the other one is the 180-degree turn about the plate normal
        assert any(abs(e[1] - 180.0) < 0.5 for e in top_two), top_two


def test_asymmetric_plate_is_not_ambiguous():
    for res, _, _ in plate_captures("planar_plate", 6, 4):
        assert res.verdict == "ok", res.summary()
        assert res.score_gap > 1.5 * PLANAR.ambiguity_gap  # measured >= 0.2 (symmetric plate: <= 0.02)


def test_feature_part_from_any_rotation_capture_against_capture():
    """seed 000 method A with a captured template (1280 x 960, ~65k points): vgr's default global
    matcher (planar sweep + FPFH/RANSAC hypotheses, GICP) from any rotation about the part normal."""
    cam = scenes.camera(1280, 960)
    rng = np.random.default_rng(7)
    tmpl = scenes.capture("feature_part", scenes.nominal_pose("feature_part"), cam, rng)
    template = prepare_cloud(tmpl.points)
    for _ in range(5):
        pose = scenes.perturbed_pose("feature_part", rng, max_shift_m=0.03, max_tilt_deg=15, spin_deg=None)
        cur = scenes.capture("feature_part", pose, cam, rng)
        res = register_global(cur.points, template, GlobalParams())
        assert res.verdict == "ok", res.summary()
        err = scenes.match_error(res.T_match, tmpl, cur, "feature_part")
        assert err[0] < 0.1 and err[1] < 0.05, err
