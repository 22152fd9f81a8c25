"""Template store: make / save / load round trips, versioned schema, refusal of damaged files, and a
stored template used by the matchers (with the photo pose kept)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import open3d as o3d
import pytest
import registration_scenes as scenes

from engine import transforms as tf
from plugins.registration import (
    FeatureFrameParams,
    InvalidInputError,
    PreprocessParams,
    RoiBox,
    load_template,
    make_template,
    register_feature_frame,
    register_fine,
    save_template,
)
from plugins.registration.template import SCHEMA_VERSION

T_PHOTO = tf.T_from_rotvec([0.1, -0.2, 0.3], [0.4, 0.1, 0.6])


@pytest.fixture(scope="module")
def captures():
    cam = scenes.camera(640, 480)
    rng = np.random.default_rng(9)
    return scenes.capture_pair("feature_part", cam, rng, max_shift_m=0.005, max_tilt_deg=2, spin_deg=2)


def test_cloud_template_round_trip_and_use(tmp_path, captures):
    tmpl, cur = captures
    roi = RoiBox.from_bounds([-0.12, -0.1, 0.3], [0.12, 0.1, 0.7])
    t = make_template(
        tmpl.points, T_PHOTO, name="part_a", preprocess=PreprocessParams(roi=roi), metadata={"by": "test"}
    )
    path = save_template(t, tmp_path)
    assert path.name == "part_a.vgrtpl" and (path / "points.npy").is_file()
    doc = json.loads((path / "template.json").read_text())
    assert doc["schema"] == "vgr.template" and doc["schema_version"] == SCHEMA_VERSION
    loaded = load_template(path)
    assert loaded.kind == "cloud" and loaded.name == "part_a" and loaded.metadata == {"by": "test"}
    assert np.array_equal(loaded.T_base_tcp_photo, t.T_base_tcp_photo)
    assert np.array_equal(loaded.points, t.points)
    # full resolution: every cropped point is kept (the 2 mm voxel grid would keep ~1/5 of them)
    assert loaded.points_resolution == "full" and doc["points_resolution"] == "full"
    inside = roi.to_open3d().get_point_indices_within_bounding_box(o3d.utility.Vector3dVector(tmpl.points))
    assert len(loaded.points) == len(inside)
    assert len(loaded.prepared().points) < len(loaded.points) / 3
    assert loaded.prepared() is loaded.prepared()  # prepared once, reused with its caches
    assert loaded.preprocess["roi"]["extent"] == pytest.approx([0.24, 0.2, 0.4])
    res = register_fine(cur.points, loaded.prepared(), None)
    assert res.verdict == "ok", res.summary()
    err = scenes.match_error(res.T_match, tmpl, cur, "feature_part")
    assert err[0] < 0.1 and err[1] < 0.05


def test_feature_frame_template_round_trip(tmp_path):
    cam = scenes.camera(1280, 960)
    rng = np.random.default_rng(2)
    params = FeatureFrameParams(feature_kind="pin", radius_m=0.0025)
    cap = scenes.capture("planar_plate", scenes.nominal_pose("planar_plate"), cam, rng)
    t = make_template(cap.points, T_PHOTO, name="plate", kind="feature_frame", feature_params=params)
    loaded = load_template(save_template(t, tmp_path))
    assert loaded.kind == "feature_frame" and loaded.points is None
    assert np.allclose(loaded.frame.T_cam_frame, t.frame.T_cam_frame)
    assert loaded.preprocess["feature_params"]["feature_kind"] == "pin"
    res = register_feature_frame(cap.points, loaded.frame, params)
    assert res.verdict == "ok" and np.allclose(res.T_match, np.eye(4), atol=1e-3)


def test_loader_refuses_damaged_or_foreign_templates(tmp_path, captures):
    tmpl, _ = captures
    path = save_template(make_template(tmpl.points, T_PHOTO, name="x"), tmp_path)
    meta = path / "template.json"
    doc = json.loads(meta.read_text())

    def write(**changes):
        meta.write_text(json.dumps({**doc, **changes}))

    write(schema_version=SCHEMA_VERSION + 1)
    with pytest.raises(InvalidInputError, match="not supported"):
        load_template(path)
    write(schema="something.else")
    with pytest.raises(InvalidInputError, match="schema"):
        load_template(path)
    write(T_base_tcp_photo=np.diag([2.0, 1, 1, 1]).tolist())
    with pytest.raises(InvalidInputError, match="T_base_tcp_photo"):
        load_template(path)
    write()
    np.save(path / "points.npy", np.zeros((10, 3)))
    with pytest.raises(InvalidInputError, match="checksum"):
        load_template(path)
    with pytest.raises(InvalidInputError, match=r"no template at .*missing \(make one with `vgr template make`\)"):
        load_template(tmp_path / "missing")  # a wrong path is said to be missing, not to be a foreign folder
    (tmp_path / "empty").mkdir()
    with pytest.raises(InvalidInputError, match=r"not a vgr template \(no template\.json\)"):
        load_template(tmp_path / "empty")
    with pytest.raises(InvalidInputError, match="is a file; a vgr template is a folder"):
        load_template(meta)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"name": ""}, "name"),
        ({"name": "a/b"}, "name"),
        ({"name": "ok", "kind": "mesh"}, "kind"),
    ],
)
def test_make_template_rejects_bad_arguments(kwargs, match, captures):
    tmpl, _ = captures
    with pytest.raises(InvalidInputError, match=match):
        make_template(tmpl.points, T_PHOTO, **kwargs)


def test_make_template_rejects_bad_photo_pose_and_cloud(captures):
    tmpl, _ = captures
    with pytest.raises(InvalidInputError, match="T_base_tcp_photo"):
        make_template(tmpl.points, np.full((4, 4), np.nan), name="a")
    with pytest.raises(InvalidInputError, match="empty"):
        make_template(np.zeros((0, 3)), T_PHOTO, name="a")


def test_version_1_templates_still_load_and_match(tmp_path, captures):
    """Templates written before schema 2 stored the points downsampled at their voxel size; they
    load as such (points_resolution "voxel", used as they are) and still match."""
    tmpl, cur = captures
    t = make_template(tmpl.points, T_PHOTO, name="old", preprocess=PreprocessParams(voxel_size_m=0.001))
    path = save_template(t, tmp_path)
    # rewrite it the way vgr 1 did: 1 mm voxel points, schema_version 1, no points_resolution
    down = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tmpl.points)).voxel_down_sample(0.001).points)
    np.save(path / "points.npy", down, allow_pickle=False)
    doc = json.loads((path / "template.json").read_text())
    del doc["points_resolution"]
    doc.update(
        schema_version=1,
        n_points=len(down),
        points_sha256=hashlib.sha256((path / "points.npy").read_bytes()).hexdigest(),
    )
    (path / "template.json").write_text(json.dumps(doc))
    old = load_template(path)
    assert old.schema_version == 1 and old.points_resolution == "voxel"
    prepared = old.prepared()
    assert len(prepared.points) == len(down) and prepared.voxel_size_m == 0.001
    res = register_fine(cur.points, prepared, None)
    assert res.verdict == "ok", res.summary()
    err = scenes.match_error(res.T_match, tmpl, cur, "feature_part")
    assert err[0] < 0.1 and err[1] < 0.05


def test_remaking_a_template_that_fails_midway_keeps_the_old_one(tmp_path, captures, monkeypatch):
    """Re-making a template recipes use: if writing the new one fails after its points are written
    (disk full, kill), the old template still loads and nothing half-written is left."""
    from plugins.registration import template as template_mod

    tmpl, _ = captures
    path = save_template(make_template(tmpl.points, T_PHOTO, name="in_use"), tmp_path)
    before = {f.name: f.read_bytes() for f in path.iterdir()}
    write_points_only = template_mod._write_template

    def fail_after_points(template, where):
        write_points_only(template, where)
        (where / "template.json").unlink()
        raise OSError("No space left on device")

    monkeypatch.setattr(template_mod, "_write_template", fail_after_points)
    with pytest.raises(OSError, match="No space"):
        save_template(make_template(tmpl.points[::2], T_PHOTO, name="in_use"), tmp_path)
    assert {f.name: f.read_bytes() for f in path.iterdir()} == before
    assert len(load_template(path).points) == len(tmpl.points)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in_use.vgrtpl"]  # no .partial / .old left


def test_template_from_a_recording_names_the_point_cloud_topics_that_hold_messages(tmp_path):
    from plugins.registration.cli import _from_recording
    from plugins.registration.validation import InvalidInputError

    rec = "recordings/sim_capture.mcap"
    with pytest.raises(InvalidInputError) as e:
        _from_recording(rec, "/capture/clouds", "/capture/pose", 0)
    msg = str(e.value)
    assert "has no topic /capture/clouds" in msg and "/capture/cloud (2)" in msg
    assert "/robot/" not in msg  # only point-cloud topics are offered, with their message counts
    points, T = _from_recording(rec, "/capture/cloud", "/capture/pose", 0)
    assert points.shape[1] == 3 and T.shape == (4, 4)
