"""file_camera: real PCL scans (PCD), generated PLY and NPZ frames, order, looping, errors naming the file."""

from __future__ import annotations

import shutil

import numpy as np
import open3d as o3d
import pytest
from adapter_context import make_stage
from depth_scenes import INTR, plane_depth, plane_residual_m
from shared_data import SHARED

from engine.messages import Request
from plugins.devices.frame_files import FrameFileError, load_frame
from plugins.devices.stages.file_camera import FileCamera

PCL = SHARED / "pcl"
PCL_FILES = {"bun0.pcd": 397, "bun4.pcd": 361, "milk.pcd": 13704, "sac_plane_test.pcd": 3283}  # README counts


def file_camera(**params):
    stage, ctx = make_stage(FileCamera, params, name="files")
    stage.setup()
    return stage, ctx


def capture(stage):
    return stage.on_request("capture", Request())


def test_plays_the_real_pcl_scans_in_name_order_with_their_normals():
    stage, ctx = file_camera(folder=str(PCL), pattern="*.pcd")
    clouds = [capture(stage) for _ in PCL_FILES]
    assert [len(c.points) for c in clouds] == list(PCL_FILES.values())
    assert all(c.frame_id == "camera" and c.points.dtype == np.float32 for c in clouds)
    # bun0.pcd, first line of DATA ascii: x y z normal_x normal_y normal_z curvature
    np.testing.assert_allclose(clouds[0].points[0], [0.0054215998, 0.11349, 0.040748999], rtol=1e-7)
    np.testing.assert_allclose(clouds[0].normals[0], [-0.16884723, -0.45159745, -0.87609947], rtol=1e-7)
    assert clouds[1].normals is None  # bun4.pcd has xyz only
    assert ctx.published["depth"] == [] and ctx.published["camera_info"] == []  # a PCD has no depth image
    assert len(ctx.published["cloud"]) == 4
    with pytest.raises(FrameFileError, match=r"all 4 frames of .*pcl were played \(set loop: true"):
        capture(stage)


def test_binary_compressed_pcd_matches_open3d_and_loop_starts_over():
    stage, _ = file_camera(folder=str(PCL), pattern="milk.pcd", loop=True)
    first, second = capture(stage), capture(stage)
    ref = np.asarray(o3d.io.read_point_cloud(str(PCL / "milk.pcd")).points)
    np.testing.assert_allclose(first.points, ref, rtol=1e-6)
    np.testing.assert_array_equal(first.points, second.points)


def test_cloud_decimate_thins_the_published_cloud_and_not_the_reply():
    stage, ctx = file_camera(folder=str(PCL), pattern="bun0.pcd", cloud_decimate=10)  # with normals
    reply = capture(stage)
    (shown,) = ctx.published["cloud"]
    assert len(reply.points) == PCL_FILES["bun0.pcd"] and len(shown.points) == -(-len(reply.points) // 10)
    np.testing.assert_array_equal(shown.points, reply.points[::10])
    np.testing.assert_array_equal(shown.normals, reply.normals[::10])
    assert shown.frame_id == reply.frame_id == "camera"


def test_natural_order_and_pattern(tmp_path):
    for name in ["f10.npz", "f2.npz", "f1.npz", "notes.txt"]:
        if name.endswith(".npz"):
            np.savez(tmp_path / name, points=np.full((3, 3), float(name[1:-4])))
        else:
            (tmp_path / name).write_text("ignored")
    stage, _ = file_camera(folder=str(tmp_path))
    assert [float(capture(stage).points[0, 0]) for _ in range(3)] == [1.0, 2.0, 10.0]


def test_ply_with_normals_and_colours_round_trips(tmp_path):
    rng = np.random.default_rng(5)
    pts = rng.uniform(-0.2, 0.2, (500, 3)) + np.array([0.0, 0.0, 0.7])
    nrm = rng.normal(size=(500, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    col = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.normals = o3d.utility.Vector3dVector(nrm)
    pc.colors = o3d.utility.Vector3dVector(col / 255.0)
    o3d.io.write_point_cloud(str(tmp_path / "scan.ply"), pc)
    stage, _ = file_camera(folder=str(tmp_path), unit_scale_m=0.5)
    cloud = capture(stage)
    np.testing.assert_allclose(cloud.points, pts * 0.5, rtol=1e-6)
    np.testing.assert_allclose(cloud.normals, nrm, atol=1e-6)
    np.testing.assert_array_equal(cloud.colors, col)


def test_npz_points_organised_with_nan_holes_normals_and_float_colours(tmp_path):
    pts = np.random.default_rng(1).uniform(0.1, 1.0, (6, 8, 3))
    pts[2, 3] = np.nan
    pts[4, :] = np.inf
    colors = np.random.default_rng(2).uniform(0, 1, (6, 8, 3))
    np.savez(tmp_path / "a.npz", points=pts, normals=np.ones_like(pts), colors=colors)
    cloud = capture(file_camera(folder=str(tmp_path))[0])
    keep = np.all(np.isfinite(pts.reshape(-1, 3)), axis=1)
    assert len(cloud.points) == 48 - 1 - 8
    np.testing.assert_allclose(cloud.points, pts.reshape(-1, 3)[keep], rtol=1e-6)
    np.testing.assert_array_equal(cloud.colors, np.round(colors.reshape(-1, 3)[keep] * 255).astype(np.uint8))


def test_npz_depth_and_K_are_deprojected_and_published_in_millimetre_files(tmp_path):
    depth_mm = plane_depth() * 1000.0
    depth_mm[10:12, 20:25] = 0.0  # no measurement
    np.savez(tmp_path / "d.npz", depth=depth_mm, K=INTR.K)
    stage, ctx = file_camera(folder=str(tmp_path), unit_scale_m=0.001)
    cloud = capture(stage)
    assert len(cloud.points) == INTR.width * INTR.height - 10
    assert plane_residual_m(cloud.points).max() < 1e-6
    depth = ctx.published["depth"][-1]
    assert np.isnan(depth.data[10:12, 20:25]).all()
    np.testing.assert_allclose(depth.data[0, 0], plane_depth()[0, 0], rtol=1e-6)
    np.testing.assert_allclose(ctx.published["camera_info"][-1].K, INTR.K)


def test_decimate_keeps_every_nth_point(tmp_path):
    np.savez(tmp_path / "a.npz", points=np.arange(30.0).reshape(10, 3))
    cloud = capture(file_camera(folder=str(tmp_path), decimate=3)[0])
    np.testing.assert_array_equal(cloud.points[:, 0], [0.0, 9.0, 18.0, 27.0])


# ----------------------------------------------------------------------------- errors


def test_empty_or_missing_folders_are_errors_naming_the_folder(tmp_path):
    (tmp_path / "readme.txt").write_text("x")
    with pytest.raises(FrameFileError, match=rf"no PLY/PCD/NPZ frame files in {tmp_path} matching '\*' \(readme.txt"):
        file_camera(folder=str(tmp_path))
    with pytest.raises(FrameFileError, match="does not exist"):
        file_camera(folder=str(tmp_path / "nope"))


@pytest.mark.parametrize(
    ("name", "write", "expect"),
    [
        ("bad.pcd", lambda p: p.write_text("garbage\n"), "bad.pcd: Open3D read no points"),
        ("bad.ply", lambda p: p.write_bytes(b"\x00\x01"), "bad.ply: Open3D read no points"),
        ("bad.npz", lambda p: p.write_bytes(b"not a zip"), "bad.npz: not a readable .npz file"),
        ("k.npz", lambda p: np.savez(p, point=np.zeros((2, 3))), r"k.npz: unknown keys \['point'\]"),
        ("d.npz", lambda p: np.savez(p, depth=np.ones((4, 4))), "d.npz: has 'depth' but no 'K'"),
        ("s.npz", lambda p: np.savez(p, points=np.zeros((4, 2))), r"s.npz: points must be \(N, 3\)"),
        ("n.npz", lambda p: np.savez(p, points=np.zeros((4, 3)), normals=np.zeros((3, 3))), "n.npz: normals has shape"),
        ("c.npz", lambda p: np.savez(p, points=np.zeros((2, 3)), colors=np.full((2, 3), 2.0)), "c.npz: colors must be"),
        ("e.npz", lambda p: np.savez(p, K=np.eye(3)), "e.npz: needs 'points', or 'depth' with 'K'"),
        ("q.npz", lambda p: np.savez(p, depth=np.ones((4, 4)), K=np.ones((3, 3))), r"q.npz: K must be \[\[fx, 0, cx\]"),
    ],
)
def test_an_unusable_file_is_an_error_naming_it_and_the_reason(tmp_path, name, write, expect):
    write(tmp_path / name)
    stage, _ = file_camera(folder=str(tmp_path))
    with pytest.raises(FrameFileError, match=expect):
        capture(stage)


def test_the_file_after_a_bad_one_still_plays(tmp_path):
    (tmp_path / "1.pcd").write_text("garbage\n")
    np.savez(tmp_path / "2.npz", points=np.ones((5, 3)))
    stage, _ = file_camera(folder=str(tmp_path))
    with pytest.raises(FrameFileError, match=r"1\.pcd"):
        capture(stage)
    assert len(capture(stage).points) == 5


def test_load_frame_refuses_unknown_types(tmp_path):
    p = tmp_path / "x.xyz"
    shutil.copy(__file__, p)
    with pytest.raises(FrameFileError, match=r"unsupported frame file type '\.xyz'"):
        load_frame(p)
