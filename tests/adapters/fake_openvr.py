"""A fake ``openvr`` module (pyopenvr's interface) with scripted devices, for tests without SteamVR.

Constants have pyopenvr 2.x's values; ``TrackedDevicePose_t`` / ``HmdMatrix34_t`` are ctypes
structures with the real field names and layout (float m[3][4], row-major). Devices are scripted
as ``FakeDevice`` entries in slots of the 64-device table; ``getDeviceToAbsoluteTrackingPose``
fills the caller's array from them, like the real call, and logs the universe it was asked for.
"""

from __future__ import annotations

import ctypes
import sys
import types
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plugins.devices.openvr_poses import hmd34_from_T

k_unMaxTrackedDeviceCount = 64


class HmdMatrix34_t(ctypes.Structure):  # noqa: N801 (OpenVR's name)
    _fields_ = [("m", (ctypes.c_float * 4) * 3)]


class HmdVector3_t(ctypes.Structure):  # noqa: N801
    _fields_ = [("v", ctypes.c_float * 3)]


class TrackedDevicePose_t(ctypes.Structure):  # noqa: N801
    _fields_ = [
        ("mDeviceToAbsoluteTracking", HmdMatrix34_t),
        ("vVelocity", HmdVector3_t),
        ("vAngularVelocity", HmdVector3_t),
        ("eTrackingResult", ctypes.c_uint),
        ("bPoseIsValid", ctypes.c_ubyte),
        ("bDeviceIsConnected", ctypes.c_ubyte),
    ]


@dataclass
class FakeDevice:
    serial: str
    device_class: int = 3  # GenericTracker
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    pose_valid: bool = True
    result: int = 200  # Running_OK
    connected: bool = True


@dataclass
class FakeOpenVR:
    devices: dict[int, FakeDevice] = field(default_factory=dict)
    init_error: Exception | None = None
    initialised: int = 0
    shutdowns: int = 0
    app_types: list[int] = field(default_factory=list)
    universes: list[int] = field(default_factory=list)
    predictions: list[float] = field(default_factory=list)
    pose_calls: int = 0
    on_pose_call: Any = None  # called with this state before each pose query (scripted changes)


class _VRSystem:
    def __init__(self, state: FakeOpenVR) -> None:
        self.state = state

    def getTrackedDeviceClass(self, index: int) -> int:
        d = self.state.devices.get(index)
        return 0 if d is None else d.device_class

    def getStringTrackedDeviceProperty(self, index: int, prop: int) -> str:
        assert prop == 1002, "only Prop_SerialNumber_String is faked"
        return self.state.devices[index].serial

    def getDeviceToAbsoluteTrackingPose(self, origin: int, predicted: float, poses: Any) -> Any:
        assert isinstance(poses, ctypes.Array) and len(poses) == k_unMaxTrackedDeviceCount
        self.state.pose_calls += 1
        if self.state.on_pose_call is not None:
            self.state.on_pose_call(self.state)
        self.state.universes.append(origin)
        self.state.predictions.append(predicted)
        for i in range(k_unMaxTrackedDeviceCount):
            d = self.state.devices.get(i)
            pose = poses[i]
            if d is None:
                pose.bDeviceIsConnected = 0
                pose.bPoseIsValid = 0
                pose.eTrackingResult = 1
                continue
            for r, row in enumerate(hmd34_from_T(d.T)):
                for c, v in enumerate(row):
                    pose.mDeviceToAbsoluteTracking.m[r][c] = v
            pose.eTrackingResult = d.result
            pose.bPoseIsValid = int(d.pose_valid)
            pose.bDeviceIsConnected = int(d.connected)
        return poses


def make_module(state: FakeOpenVR) -> types.ModuleType:
    mod = types.ModuleType("openvr")
    mod.k_unMaxTrackedDeviceCount = k_unMaxTrackedDeviceCount  # type: ignore[attr-defined]
    mod.VRApplication_Other = 0  # type: ignore[attr-defined]
    mod.Prop_SerialNumber_String = 1002  # type: ignore[attr-defined]
    mod.TrackingUniverseSeated = 0  # type: ignore[attr-defined]
    mod.TrackingUniverseStanding = 1  # type: ignore[attr-defined]
    mod.TrackingUniverseRawAndUncalibrated = 2  # type: ignore[attr-defined]
    mod.TrackedDevicePose_t = TrackedDevicePose_t  # type: ignore[attr-defined]

    def init(application_type: int, startup_info: Any = None) -> _VRSystem:
        state.app_types.append(application_type)
        if state.init_error is not None:
            raise state.init_error
        state.initialised += 1
        return _VRSystem(state)

    def shutdown() -> None:
        state.shutdowns += 1

    mod.init = init  # type: ignore[attr-defined]
    mod.shutdown = shutdown  # type: ignore[attr-defined]
    return mod


def install(monkeypatch: Any, state: FakeOpenVR) -> None:
    monkeypatch.setitem(sys.modules, "openvr", make_module(state))
