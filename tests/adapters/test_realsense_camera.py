"""realsense_camera: metres from the depth scale, intrinsics from the profile, live vs recording, errors.

Against a fake pyrealsense2 always; against the real pyrealsense2 (when installed) on recordings it
writes itself through a software device, so the playback path runs through librealsense.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
from adapter_context import make_stage
from depth_scenes import INTR, PLANE_POINT, plane_depth, plane_residual_m, write_recording, z16_of
from fake_realsense import FakeCamera, Intrinsics, distortion, format, install, stream

from engine.messages import Request
from plugins.devices.realsense_device import EndOfRecordingError, RealSenseError
from plugins.devices.stages.realsense_camera import RealSenseCamera
from plugins.util.sdk import MissingSDKError

SCALE = 0.0001  # 0.1 mm per z16 unit (D405-like); most D400 cameras use 1 mm
RS_INTR = Intrinsics(INTR.width, INTR.height, INTR.fx, INTR.fy, INTR.cx, INTR.cy)


def plane_frames(n: int, scale: float = SCALE) -> list[np.ndarray]:
    """n frames of the plane, each moved 1 mm farther along z, a hole of no-depth pixels in each."""
    frames = []
    for k in range(n):
        z16 = z16_of(plane_depth(p0=PLANE_POINT + np.array([0.0, 0.0, 0.001 * k])), scale)
        z16[20:24, 30:36] = 0
        frames.append(z16)
    return frames


@pytest.fixture
def cam(monkeypatch) -> FakeCamera:
    c = FakeCamera(frames=plane_frames(40), intrinsics=RS_INTR, depth_scale=SCALE)
    install(monkeypatch, c)
    return c


def camera(**params):
    stage, ctx = make_stage(RealSenseCamera, {"width": INTR.width, "height": INTR.height, **params}, name="cam")
    stage.setup()
    return stage, ctx


def test_live_capture_is_metres_on_the_plane_with_the_profile_intrinsics(cam):
    stage, ctx = camera(serial="123456789", warmup_frames=5)
    assert cam.device_serial == "123456789"
    assert cam.streams == [(stream.depth, INTR.width, INTR.height, format.z16, 30)]
    assert cam.waits == 5  # warm-up frames discarded
    cloud = stage.on_request("capture", Request())
    assert cam.polls == 1 and cam.waits == 6  # the waiting frame set was dropped, the next one taken
    assert cloud.frame_id == "camera" and cloud.points.dtype == np.float32
    assert len(cloud.points) == INTR.width * INTR.height - 24  # the no-depth hole is not in the cloud
    # frame 6 (after 5 warm-up + 1 dropped) is the plane moved 6 mm along z: n . p = n . p0 + 6 mm * n_z
    n = np.array([0.2, -0.3, -1.0]) / np.linalg.norm([0.2, -0.3, -1.0])
    resid = np.abs(plane_residual_m(cloud.points) - abs(0.006 * n[2]))
    assert resid.max() < 0.6 * SCALE  # z16 quantisation (half a unit) is all that is left
    depth = ctx.published["depth"][-1]
    assert depth.encoding == "32FC1" and depth.data.shape == (INTR.height, INTR.width)
    assert np.isnan(depth.data[20:24, 30:36]).all()
    np.testing.assert_allclose(depth.data[0, 0], cam.frames[6][0, 0] * SCALE, rtol=1e-6)
    info = ctx.published["camera_info"][-1]
    np.testing.assert_allclose(info.K, INTR.K)
    assert info.distortion_model == "plumb_bob" and (info.width, info.height) == (INTR.width, INTR.height)
    np.testing.assert_array_equal(ctx.published["cloud"][-1].points, cloud.points)


def test_depth_scale_of_the_device_is_applied(monkeypatch):
    z16 = np.full((INTR.height, INTR.width), 500, np.uint16)
    c = FakeCamera(frames=[z16], intrinsics=RS_INTR, depth_scale=0.001)
    install(monkeypatch, c)
    stage, _ = camera(warmup_frames=0)
    cloud = stage.on_request("capture", Request())
    np.testing.assert_allclose(cloud.points[:, 2], 0.5, rtol=1e-6)


def test_depth_range_limits_drop_points(cam):
    stage, ctx = camera(warmup_frames=0, min_depth_m=0.58, max_depth_m=0.62)
    cloud = stage.on_request("capture", Request())
    z = cloud.points[:, 2]
    assert z.min() >= 0.58 and z.max() <= 0.62 and 0 < len(z) < INTR.width * INTR.height - 24
    assert np.isnan(ctx.published["depth"][-1].data).sum() == INTR.width * INTR.height - len(z)


def test_color_aligns_depth_to_the_colour_camera_and_colours_the_points(monkeypatch):
    colors = [np.random.default_rng(k).integers(0, 256, (INTR.height, INTR.width, 3), dtype=np.uint8) for k in range(3)]
    color_intr = Intrinsics(
        INTR.width, INTR.height, 72.0, 72.0, 40.0, 30.0, distortion.inverse_brown_conrady, [0.0] * 5
    )
    c = FakeCamera(plane_frames(3), RS_INTR, depth_scale=SCALE, colors=colors, color_intrinsics=color_intr)
    install(monkeypatch, c)
    stage, ctx = camera(warmup_frames=0, color=True)
    assert (stream.color, INTR.width, INTR.height, format.rgb8, 30) in c.streams
    cloud = stage.on_request("capture", Request())  # frame 1 (frame 0 was dropped as stale)
    assert c.aligned >= 1  # depth went through rs.align to the colour camera before use
    keep = c.frames[1].reshape(-1) > 0
    np.testing.assert_array_equal(cloud.colors, colors[1].reshape(-1, 3)[keep])
    np.testing.assert_allclose(ctx.published["camera_info"][-1].K[0, 0], 72.0)  # the colour camera's


def test_recording_plays_every_frame_in_order_then_says_so(cam, tmp_path):
    rec = tmp_path / "cell.bag"
    rec.write_bytes(b"not read by the fake")
    cam.frames = plane_frames(3)
    stage, _ = camera(recording=str(rec))
    assert cam.recording == str(rec) and cam.real_time_when_started == [False]  # not real time from the start
    assert cam.opened == [[stream.depth]] and cam.streams == [] and cam.waits == 0  # the file's streams, no warm-up
    zs = [float(np.nanmedian(stage.on_request("capture", Request()).points[:, 2])) for _ in range(3)]
    assert np.all(np.diff(zs) > 0.0009)  # frames 0, 1, 2: each 1 mm farther
    with pytest.raises(EndOfRecordingError, match=r"every frame of .*cell.bag was played \(3 frame sets; set loop"):
        stage.on_request("capture", Request())


def test_recording_loops_when_asked(cam, tmp_path):
    rec = tmp_path / "cell.db3"
    rec.write_bytes(b"x")
    cam.frames = plane_frames(2)
    stage, _ = camera(recording=str(rec), loop=True)
    zs = [float(np.nanmedian(stage.on_request("capture", Request()).points[:, 2])) for _ in range(5)]
    assert zs[0] == zs[2] == zs[4] and zs[1] == zs[3] and zs[1] > zs[0]
    assert cam.loads == 3 and cam.sensors_stopped == 2  # reopened at each end, the old sensors released


@pytest.mark.parametrize(
    ("setup", "params", "expect"),
    [
        (lambda c, p: None, {"recording": "/nonexistent/cell.bag"}, "recording /nonexistent/cell.bag does not exist"),
        (lambda c, p: (p / "x.mp4").write_bytes(b"x"), {"recording": "{tmp}/x.mp4"}, "is a .bag or .db3 file"),
        (
            lambda c, p: setattr(c, "start_error", RuntimeError("No device connected")),
            {"serial": "999"},
            "cannot start a RealSense camera with serial 999 at 80x60 @ 30 fps: No device connected. Check: the camera is plugged into a USB 3 port",
        ),
        (
            lambda c, p: setattr(
                c,
                "intrinsics",
                Intrinsics(80, 60, 50, 50, 40, 30, distortion.modified_brown_conrady, [0.1, 0, 0, 0, 0]),
            ),
            {},
            "'modified_brown_conrady' is not supported",
        ),
        (
            lambda c, p: ((p / "d.db3").write_bytes(b"x"), setattr(c, "recording_has_color", False)),
            {"recording": "{tmp}/d.db3", "color": True},
            "has no colour stream",
        ),
    ],
)
def test_setup_errors_say_what_is_wrong(cam, tmp_path, setup, params, expect):
    setup(cam, tmp_path)
    params = {k: v.format(tmp=tmp_path) if isinstance(v, str) else v for k, v in params.items()}
    stage, _ = make_stage(RealSenseCamera, {"width": 80, "height": 60, **params})
    with pytest.raises((RealSenseError, ValueError), match=expect):
        stage.setup()


def test_librealsense_distortion_models_map_onto_the_camera_models():
    from plugins.devices.realsense_device import intrinsics_from_rs

    D = [0.1, -0.02, 0.001, 0.002, 0.03]
    cases = {"none": ("standard", [0.0] * 5), "brown_conrady": ("standard", D)}
    cases |= {"inverse_brown_conrady": ("inverse_brown_conrady", D), "kannala_brandt4": ("fisheye", D[:4])}
    for rs_name, (model, coeffs) in cases.items():
        rs_D = [0.5] * 5 if rs_name == "none" else D  # librealsense ignores the coefficients of 'none'
        camera = intrinsics_from_rs(Intrinsics(80, 60, 50, 51, 40, 30, getattr(distortion, rs_name), rs_D))
        assert (camera.model, camera.D.tolist(), camera.fy, camera.cx) == (model, coeffs, 51.0, 40.0)


def test_a_failed_configuration_stops_the_started_pipeline(cam):
    cam.intrinsics = Intrinsics(80, 60, 50, 50, 40, 30, distortion.ftheta, [0.5, 0, 0, 0, 0])
    stage, _ = make_stage(RealSenseCamera, {})
    with pytest.raises(ValueError, match="ftheta"):
        stage.setup()
    assert cam.stopped == 1


def test_decimate_and_teardown(cam):
    stage, _ = camera(warmup_frames=0, decimate=4)
    cloud = stage.on_request("capture", Request())
    assert len(cloud.points) == -(-(INTR.width * INTR.height - 24) // 4)
    stage.teardown()
    stage.teardown()
    assert cam.stopped == 1


def test_missing_sdk_names_the_realsense_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    stage, _ = make_stage(RealSenseCamera, {})
    with pytest.raises(MissingSDKError, match=r"'pyrealsense2'.*pip install 'vgr\[realsense\]'"):
        stage.setup()


# ----------------------------------------------------------------------------- the real pyrealsense2


@pytest.fixture
def real_rs():
    return pytest.importorskip("pyrealsense2")


def test_real_sdk_plays_a_recording_frame_by_frame_with_its_scale_and_intrinsics(real_rs, tmp_path):
    frames = plane_frames(8)
    rec = write_recording(tmp_path / "plane.db3", frames, INTR, SCALE)
    stage, ctx = camera(recording=str(rec))
    assert stage.device.depth_scale == pytest.approx(SCALE, rel=1e-6)  # stored as float32 by librealsense
    intr = stage.device.intrinsics
    assert (intr.width, intr.height, intr.model, intr.distorted) == (INTR.width, INTR.height, "standard", False)
    np.testing.assert_allclose([intr.fx, intr.fy, intr.cx, intr.cy], [INTR.fx, INTR.fy, INTR.cx, INTR.cy], rtol=1e-6)
    n = np.array([0.2, -0.3, -1.0]) / np.linalg.norm([0.2, -0.3, -1.0])
    for k in range(8):
        cloud = stage.on_request("capture", Request())
        assert len(cloud.points) == INTR.width * INTR.height - 24
        resid = np.abs(plane_residual_m(cloud.points) - abs(0.001 * k * n[2]))
        assert resid.max() < 0.6 * SCALE, (k, resid.max())  # frame k, in order, none skipped
        np.testing.assert_array_equal(np.isnan(ctx.published["depth"][-1].data), frames[k] == 0)
    with pytest.raises(EndOfRecordingError, match="8 frame sets"):
        stage.on_request("capture", Request())
    stage.teardown()


def test_real_sdk_refuses_an_unreadable_bag_naming_it(real_rs, tmp_path):
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"this is not a rosbag")
    stage, _ = make_stage(RealSenseCamera, {"recording": str(bad)})
    with pytest.raises(RealSenseError, match=r"cannot play the RealSense recording .*broken.bag"):
        stage.setup()


def test_real_sdk_loops_a_recording_in_order(real_rs, tmp_path):
    frames = plane_frames(3)
    rec = write_recording(tmp_path / "loop.db3", frames, INTR, SCALE)
    stage, ctx = camera(recording=str(rec), loop=True)
    for k in range(7):
        stage.on_request("capture", Request())
        np.testing.assert_allclose(
            ctx.published["depth"][-1].data[0, 0], frames[k % 3][0, 0] * np.float32(SCALE), rtol=1e-6
        )
    stage.teardown()
