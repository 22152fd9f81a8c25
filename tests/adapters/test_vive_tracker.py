"""vive_tracker: HmdMatrix34 conversion, validity flags, device lookup, streaming, OpenVR lifecycle."""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest
from adapter_context import make_stage
from fake_openvr import FakeDevice, FakeOpenVR, TrackedDevicePose_t, install
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import transforms as tf
from engine.messages import Request
from plugins.devices.openvr_poses import T_from_hmd34, hmd34_from_T, reading_from_pose
from plugins.devices.stages.vive_tracker import ViveTracker, ViveTrackerError
from plugins.util.sdk import MissingSDKError

T_LH_TRACKER = tf.T_from_rotvec([0.3, -1.2, 0.4], [0.52, 1.31, -2.04])


def fill(pose, m, *, result=200, valid=True, connected=True):
    for r in range(3):
        for c in range(4):
            pose.mDeviceToAbsoluteTracking.m[r][c] = m[r][c]
    pose.eTrackingResult, pose.bPoseIsValid, pose.bDeviceIsConnected = result, int(valid), int(connected)
    return pose


# ----------------------------------------------------------------------------- conversion


def test_hmd34_rows_are_R_and_t_with_the_device_axes_as_columns():
    # Written from the OpenVR wiki layout (AXx AYx AZx Tx / AXy ... ): device x axis = universe +y,
    # device y axis = universe -x, device z = universe z; origin at (0.1, 1.2, -0.3).
    m = [[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 1.2], [0.0, 0.0, 1.0, -0.3]]
    T = T_from_hmd34(m)
    np.testing.assert_allclose(T @ [1.0, 0.0, 0.0, 1.0], [0.1, 2.2, -0.3, 1.0])
    np.testing.assert_allclose(T @ [0.0, 1.0, 0.0, 1.0], [-0.9, 1.2, -0.3, 1.0])
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_conversion_with_the_real_pyopenvr_structures():
    openvr = pytest.importorskip("openvr")
    pose = fill(openvr.TrackedDevicePose_t(), hmd34_from_T(T_LH_TRACKER))
    reading = reading_from_pose(pose)
    assert reading.valid and reading.tracking_result == "Running_OK"
    dist, ang = tf.pose_error(reading.T, T_LH_TRACKER)
    assert dist < 1e-6 and ang < 1e-6  # float32 storage: ~1e-7 relative
    assert tf.is_rotation(reading.T[:3, :3], tol=1e-12)  # projected back onto SO(3)


@settings(max_examples=100, deadline=None)
@given(
    rotvec=st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
    t=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
)
def test_conversion_round_trip_through_float32_is_within_a_micrometre(rotvec, t):
    T = tf.T_from_rotvec(rotvec, t)
    reading = reading_from_pose(fill(TrackedDevicePose_t(), hmd34_from_T(T)))
    dist, ang = tf.pose_error(reading.T, T)
    assert reading.valid and dist < 1e-6 and ang < 2e-6


@pytest.mark.parametrize(
    ("kw", "m_edit", "result_name", "reason"),
    [
        ({"connected": False}, None, "Disconnected", "not connected"),
        ({"valid": False}, None, "Running_OK", "bPoseIsValid"),
        ({"result": 201}, None, "Running_OutOfRange", "not Running_OK"),
        ({"result": 300}, None, "Fallback_RotationOnly", "not Running_OK"),
        ({"result": 100}, None, "Calibrating_InProgress", "not Running_OK"),
        ({"result": 77}, None, "Unknown_77", "not Running_OK"),
        ({}, (0, 3, float("nan")), "Running_OK", "NaN"),
        ({}, (1, 1, 1.2), "Running_OK", "not a rotation"),
    ],
)
def test_validity_follows_the_openvr_flags_and_the_matrix(kw, m_edit, result_name, reason):
    m = hmd34_from_T(T_LH_TRACKER)
    if m_edit:
        m[m_edit[0]][m_edit[1]] = m_edit[2]
    reading = reading_from_pose(fill(TrackedDevicePose_t(), m, **kw))
    assert not reading.valid and reading.tracking_result == result_name and reason in reading.reason
    if m_edit:
        assert reading.T is None


def test_a_nearly_orthonormal_rotation_is_projected_not_refused():
    m = hmd34_from_T(T_LH_TRACKER)
    m[0][0] += 1e-5
    reading = reading_from_pose(fill(TrackedDevicePose_t(), m))
    assert reading.valid and tf.is_rotation(reading.T[:3, :3], tol=1e-12)
    assert tf.pose_error(reading.T, T_LH_TRACKER)[1] < 2e-5


# ----------------------------------------------------------------------------- the stage


@pytest.fixture
def vr(monkeypatch) -> FakeOpenVR:
    state = FakeOpenVR(
        devices={
            0: FakeDevice("LHR-HMD", device_class=1),
            1: FakeDevice("LHB-BASE1", device_class=4),
            3: FakeDevice("LHR-TRACK01", T=T_LH_TRACKER),
        }
    )
    install(monkeypatch, state)
    return state


def tracker(**params):
    stage, ctx = make_stage(ViveTracker, params, name="tracker")
    stage.setup()
    return stage, ctx


def test_setup_initialises_openvr_as_other_app_and_finds_the_only_tracker(vr):
    stage, ctx = tracker()
    assert vr.app_types == [0] and vr.initialised == 1
    assert stage.device.serial == "LHR-TRACK01" and stage.device.index == 3
    assert any(e.code == "tracker_found" for e in ctx.events)
    stage.teardown()
    stage.teardown()
    assert vr.shutdowns == 1


def test_sample_returns_a_fresh_pose_in_the_raw_universe_by_default(vr):
    stage, _ = tracker(serial="LHR-TRACK01", predict_s=0.011)
    msg = stage.on_request("sample", Request())
    assert msg.valid and msg.serial == "LHR-TRACK01" and msg.frame_id == "lighthouse"
    assert msg.tracking_result == "Running_OK"
    assert tf.pose_error(msg.T, T_LH_TRACKER)[0] < 1e-6
    assert vr.universes == [2] and vr.predictions == [pytest.approx(0.011)]
    vr.devices[3].T = tf.T_from_rotvec([0, 0, 0], [1, 2, 3])
    assert tf.pose_error(stage.on_request("sample", Request()).T, vr.devices[3].T)[0] < 1e-6


def test_standing_universe_is_requested_when_configured(vr):
    stage, _ = tracker(universe="standing")
    stage.on_request("sample", Request())
    assert vr.universes == [1]


def test_stream_publishes_at_the_rate_for_the_duration(vr):
    stage, ctx = tracker(stream_hz=50.0, duration_s=0.2)
    stage.run()
    poses = ctx.published["pose"]
    assert len(poses) == 10 and all(p.valid for p in poses)
    assert np.all(np.diff([p.stamp_ns for p in poses]) == 20_000_000)


def test_lost_and_regained_tracking_raise_events_and_invalid_readings_are_flagged(vr):
    def script(state: FakeOpenVR) -> None:
        state.devices[3].result = 201 if 4 <= state.pose_calls <= 6 else 200

    vr.on_pose_call = script
    stage, ctx = tracker(stream_hz=10.0, duration_s=1.0)
    stage.run()
    valid = [p.valid for p in ctx.published["pose"]]
    assert valid == [True] * 3 + [False] * 3 + [True] * 4
    assert {p.tracking_result for p in ctx.published["pose"] if not p.valid} == {"Running_OutOfRange"}
    codes = [e.code for e in ctx.events if e.code.startswith("tracking")]
    assert codes == ["tracking_ok", "tracking_lost", "tracking_ok"]


def test_publish_invalid_false_skips_invalid_readings(vr):
    vr.devices[3].pose_valid = False
    stage, ctx = tracker(stream_hz=10.0, duration_s=0.5, publish_invalid=False)
    stage.run()
    assert ctx.published["pose"] == [] and vr.pose_calls == 5


def test_a_tracker_that_reconnects_on_another_index_is_followed(vr):
    def script(state: FakeOpenVR) -> None:
        if state.pose_calls == 3:
            state.devices[3].connected = False
            state.devices[7] = FakeDevice("LHR-TRACK01", T=tf.T_from_rotvec([0, 0, 0], [0, 0, 1]))

    vr.on_pose_call = script
    stage, ctx = tracker(stream_hz=10.0, duration_s=0.6)
    stage.run()
    results = [p.tracking_result for p in ctx.published["pose"]]
    assert results == ["Running_OK"] * 2 + ["Disconnected"] + ["Running_OK"] * 3
    assert stage.device.index == 7 and any(e.code == "tracker_moved" for e in ctx.events)
    np.testing.assert_allclose(ctx.published["pose"][-1].T[:3, 3], [0, 0, 1], atol=1e-6)


@pytest.mark.parametrize(
    ("devices", "params", "expect"),
    [
        ({}, {}, "no tracker is connected (devices seen: none)"),
        ({0: FakeDevice("LHR-HMD", device_class=1)}, {}, "devices seen: LHR-HMD (hmd)"),
        ({3: FakeDevice("A"), 4: FakeDevice("B")}, {}, "2 trackers are connected (A (tracker), B (tracker))"),
        ({3: FakeDevice("A")}, {"serial": "LHR-X"}, "no OpenVR device with serial 'LHR-X'"),
    ],
)
def test_device_lookup_errors_list_what_is_connected(monkeypatch, devices, params, expect):
    state = FakeOpenVR(devices=devices)
    install(monkeypatch, state)
    stage, _ = make_stage(ViveTracker, {"wait_for_device_s": 0.3, **params})
    with pytest.raises(ViveTrackerError) as err:
        stage.setup()
    assert expect in str(err.value) and "waited 0.3 s" in str(err.value)
    stage.teardown()
    assert state.shutdowns == 1  # OpenVR was initialised, so it is shut down


def test_a_controller_can_be_followed_by_class():
    state = FakeOpenVR(devices={2: FakeDevice("CTRL", device_class=2), 3: FakeDevice("T")})
    mp = pytest.MonkeyPatch()
    install(mp, state)
    try:
        stage, _ = tracker(device_class="controller")
        assert stage.device.serial == "CTRL"
    finally:
        mp.undo()


def test_openvr_init_failure_says_what_to_check(vr):
    vr.init_error = RuntimeError("InitError_Init_HmdNotFound")
    stage, _ = make_stage(ViveTracker, {})
    with pytest.raises(ViveTrackerError, match=r"OpenVR could not start .*HmdNotFound.*SteamVR is running"):
        stage.setup()
    stage.teardown()
    assert vr.shutdowns == 0


@pytest.mark.skipif(
    (Path.home() / ".config/openvr/openvrpaths.vrpath").exists(), reason="a SteamVR install exists: would really init"
)
def test_the_real_pyopenvr_without_steamvr_fails_with_the_hint():
    pytest.importorskip("openvr")
    stage, _ = make_stage(ViveTracker, {})
    with pytest.raises(ViveTrackerError, match=r"InitError_Init_PathRegistryNotFound.*openvrpaths.vrpath"):
        stage.setup()


def test_missing_sdk_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "openvr", None)
    stage, _ = make_stage(ViveTracker, {})
    with pytest.raises(MissingSDKError, match=r"'openvr'.*pip install 'vgr\[vive\]'"):
        stage.setup()


def test_pose_struct_layout_matches_pyopenvr():
    openvr = pytest.importorskip("openvr")
    assert [f[0] for f in TrackedDevicePose_t._fields_] == [f[0] for f in openvr.TrackedDevicePose_t._fields_]
    assert ctypes.sizeof(TrackedDevicePose_t) == ctypes.sizeof(openvr.TrackedDevicePose_t)
