"""The ``matcher`` stage with its DEFAULT parameters on seed 004's planar plate, end to end: the
template made by ``vgr template make`` from a capture (the teach step), the captures answered by
the stage's services as guidance calls them.

Scene (as recipes/planar_assembly.yaml): the plate held with its pin face towards a camera at
0.4-0.5 m (registration_scenes renders it in the camera frame: the same whether the camera looks up
or down), 0.1 mm depth noise, 640 x 480. The part is off the template pose by random in-plane
offsets (+-20 mm, +-10 deg about the plate normal: the grasp offsets guidance meets) or, for the
global matcher, by any spin about the normal. Success = verdict ok and the error at the part centre
< 0.5 mm and < 0.5 deg (seed 004's criterion). A WRONG 'ok' (ok with a larger error) must never
happen: guidance would move the robot on it.

Before the contour edge term (edges.py), these defaults gave 1/12 ok on the first look, 11 "did not
converge" and, on other poses, ok with the plate turned by 2-7 deg.
"""

from __future__ import annotations

import numpy as np
import pytest
import registration_scenes as scenes

from engine.cli.main import main as vgr
from engine.messages import PointCloud
from plugins.registration.stages.matcher import Matcher
from plugins.util.detached import DetachedContext

PART = "planar_plate"


@pytest.fixture(scope="module")
def stage_and_template(tmp_path_factory):
    """The teach step: one capture at the template pose, through `vgr template make --from-file`
    (its defaults), and a matcher stage with its defaults on the result."""
    out = tmp_path_factory.mktemp("tpl")
    rng = np.random.default_rng(404)
    cam = scenes.camera(640, 480)
    tmpl = scenes.capture(PART, scenes.at_distance(scenes.nominal_pose(PART), 0.45), cam, rng)
    np.savez(out / "teach.npz", points=tmpl.points)
    photo_pose = "-0.25,0.35,0.4,3.14159265,0,0"  # x,y,z (m), rotation vector (rad): any valid pose
    args = ["template", "make", "--from-file", str(out / "teach.npz"), f"--photo-pose={photo_pose}"]
    code = vgr([*args, "--name", "plate", "-o", str(out)])
    assert code == 0
    stage = Matcher(DetachedContext("matcher", seed=4), Matcher.Params(template=str(out / "plate.vgrtpl")))
    stage.setup()
    return stage, tmpl, cam, rng


def _run(stage_and_template, service: str, n: int, spin_deg: float | None, shift_m=0.02, distances=(0.4, 0.5)):
    """(rows, good, wrong) over *n* captures: rows are (verdict, (mm, deg) or None, reasons)."""
    stage, tmpl, cam, rng = stage_and_template
    rows = []
    for _ in range(n):
        pose = scenes.perturbed_pose(PART, rng, max_shift_m=shift_m, max_tilt_deg=0.0, spin_deg=spin_deg)
        cur = scenes.capture(PART, scenes.at_distance(pose, rng.uniform(*distances)), cam, rng)
        reply = stage.on_request(service, PointCloud(points=cur.points, frame_id="camera"))
        err = scenes.match_error(reply.T_match, tmpl, cur, PART) if reply.verdict == "ok" else None
        rows.append((reply.verdict, err, reply.reasons))
    good = [r for r in rows if r[0] == "ok" and r[1][0] < 0.5 and r[1][1] < 0.5]
    wrong = [r for r in rows if r[0] == "ok" and not (r[1][0] < 0.5 and r[1][1] < 0.5)]
    return rows, good, wrong


def test_first_look_global_defaults_on_the_planar_plate(stage_and_template):
    """match_first (global registration, every default) with the grasp offsets guidance meets:
    all ok and within 0.5 mm / 0.5 deg (measured 0.02-0.08 mm, 0.003-0.07 deg)."""
    rows, good, wrong = _run(stage_and_template, "match_first", 10, spin_deg=10.0)
    assert not wrong, wrong
    assert len(good) == len(rows), rows


def test_global_defaults_from_any_spin(stage_and_template):
    """The same from any rotation about the plate normal (+-180 deg): the planar sweep's flip test
    and the contour decide; all ok and within 0.5 mm / 0.5 deg."""
    rows, good, wrong = _run(stage_and_template, "match_first", 10, spin_deg=None)
    assert not wrong, wrong
    assert len(good) == len(rows), rows


def test_later_looks_fine_from_identity(stage_and_template):
    """match (fine ICP from identity) as guidance uses it: after a correction, at the photo pose,
    the plate within 2 mm / 2 deg of the template pose: all ok and within 0.5 mm / 0.5 deg."""
    rows, good, wrong = _run(stage_and_template, "match", 8, spin_deg=2.0, shift_m=0.002, distances=(0.449, 0.451))
    assert not wrong, wrong
    assert len(good) == len(rows), rows


def test_fine_far_off_refuses_rather_than_reports_a_wrong_pose(stage_and_template):
    """The lead's failure: a later look at a plate left 6 deg off by a wrong first look. match (fine
    from identity) with offsets up to 20 mm / 10 deg: ICP falls into wrong minima, and those must be
    refused (most of the contour unmatched: 'failed'), never reported ok. Measured: 4-15 of 10-16
    ok and right depending on the draws, the rest failed; none wrong."""
    rows, good, wrong = _run(stage_and_template, "match", 10, spin_deg=10.0, distances=(0.449, 0.451))
    assert not wrong, wrong
    assert good, rows
    for verdict, _, reasons in rows:
        if verdict != "ok":
            assert verdict == "failed" and reasons, (verdict, reasons)


def test_template_make_then_stage_reach_the_fine_accuracy_target(tmp_path):
    """The issue's fine target (<= 0.02 mm / 0.005 deg at 0.1 mm noise on feature_part) through the
    whole path: a 5 MP capture (seed 004's sensor class, ~240k points on the part) -> `vgr template
    make` (full-resolution points kept) -> the matcher stage with its defaults (GICP on 2 mm voxels,
    then the full-resolution polish) -> match_first on captures 20 mm / 10 deg tilt / 20 deg spin away.
    Measured: <= 0.0053 mm / 0.0033 deg over 6 captures. (Near the template pose the two captures
    sample the part on the same pixel rays and the estimate is pulled towards identity: up to
    0.017 mm / 0.02 deg measured 2 mm / 1 deg away; the pull vanishes at identity, where guidance
    converges: docs/registration.md.)"""
    rng = np.random.default_rng(1)
    cam = scenes.camera(2448, 2048)
    tmpl = scenes.capture("feature_part", scenes.nominal_pose("feature_part"), cam, rng)
    np.savez(tmp_path / "teach.npz", points=tmpl.points)
    args = ["template", "make", "--from-file", str(tmp_path / "teach.npz"), "--photo-pose=0,0,0.5,0,0,0"]
    assert vgr([*args, "--name", "part", "-o", str(tmp_path)]) == 0
    stage = Matcher(DetachedContext("matcher", seed=4), Matcher.Params(template=str(tmp_path / "part.vgrtpl")))
    stage.setup()
    assert stage.template.points_resolution == "full" and len(stage.template.points) > 200_000
    errors = []
    for _ in range(2):
        pose = scenes.perturbed_pose("feature_part", rng, max_shift_m=0.02, max_tilt_deg=10.0, spin_deg=20.0)
        cur = scenes.capture("feature_part", pose, cam, rng)
        reply = stage.on_request("match_first", PointCloud(points=cur.points, frame_id="camera"))
        assert reply.verdict == "ok", reply.reasons
        errors.append(scenes.match_error(reply.T_match, tmpl, cur, "feature_part"))
    errors = np.array(errors)
    assert errors[:, 0].max() <= 0.02 and errors[:, 1].max() <= 0.005, errors
