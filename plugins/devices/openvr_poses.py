"""OpenVR tracked-device poses -> vgr poses: the HmdMatrix34_t conversion, validity, device lookup.

Conventions (openvr.h, ``public_vrtypes.h``; OpenVR wiki "Matrix Usage Example"):

* ``HmdMatrix34_t`` is ``float m[3][4]``, row-major, holding ``[R | t]`` with the device's axes as the
  *columns* of R and its origin in ``t``. ``TrackedDevicePose_t.mDeviceToAbsoluteTracking`` maps
  device coordinates to tracking-universe coordinates ("universe from device"), so with a bottom
  row ``[0, 0, 0, 1]`` it *is* vgr's ``T_universe_device`` (``p_universe = T @ p_device``); no
  transpose, no axis swap.
* Units are metres. The tracking universes are right-handed with **+y up**, +x right and **-z
  forward** (OpenGL-style), unlike a robot base (z up). vgr keeps OpenVR's axes as they are: the
  transform between the universe and a robot or desk frame is estimated by calibration
  (seed 001: T_base_desktop), never assumed.
* ``TrackingUniverseRawAndUncalibrated`` is the driver's own frame, which SteamVR's room setup does
  not move; ``TrackingUniverseStanding`` is the room-setup play area (origin on the floor). A
  calibration against the standing universe is invalidated by re-running room setup.
* The matrix is single precision: its rotation is orthonormal to ~1e-7 only. Rotations within
  ``rotation_tol`` of orthonormal are projected onto SO(3) (nearest rotation, SVD); worse ones make
  the reading invalid.

A reading is *valid* when the device is connected, ``bPoseIsValid`` is set, ``eTrackingResult`` is
``TrackingResult_Running_OK`` and the matrix is a finite rigid transform.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine import transforms as tf

F64 = NDArray[np.float64]

RUNNING_OK = 200
TRACKING_RESULTS = {
    1: "Uninitialized",
    100: "Calibrating_InProgress",
    101: "Calibrating_OutOfRange",
    200: "Running_OK",
    201: "Running_OutOfRange",
    300: "Fallback_RotationOnly",
}
DEVICE_CLASSES = {"hmd": 1, "controller": 2, "tracker": 3, "tracking_reference": 4}
UNIVERSES = {"seated": 0, "standing": 1, "raw": 2}  # ETrackingUniverseOrigin


def T_from_hmd34(m: Any) -> F64:
    """4x4 float64 from an OpenVR HmdMatrix34_t's ``m`` (3 rows of 4), bottom row [0, 0, 0, 1]."""
    rows = np.array([[float(m[r][c]) for c in range(4)] for r in range(3)], dtype=float)
    T = np.eye(4)
    T[:3, :] = rows
    return T


def hmd34_from_T(T: Any) -> list[list[float]]:
    """The 3x4 rows OpenVR would report for the 4x4 ``T_universe_device`` (for tests and tools)."""
    A = np.asarray(T, dtype=float)
    return [[float(A[r, c]) for c in range(4)] for r in range(3)]


@dataclass(frozen=True)
class PoseReading:
    """One device pose from OpenVR, converted and judged."""

    T: F64 | None  # T_universe_device, None when the matrix is unusable
    valid: bool
    tracking_result: str
    reason: str  # why the reading is invalid ("" when valid)


def reading_from_pose(pose: Any, *, rotation_tol: float = 1e-3) -> PoseReading:
    """Convert an OpenVR ``TrackedDevicePose_t`` and decide whether it can be used."""
    connected = bool(pose.bDeviceIsConnected)
    result = int(pose.eTrackingResult)
    name = TRACKING_RESULTS.get(result, f"Unknown_{result}")
    T = T_from_hmd34(pose.mDeviceToAbsoluteTracking.m)
    if not np.all(np.isfinite(T)):
        return PoseReading(None, False, name, "the pose matrix contains NaN or infinity")
    R = T[:3, :3]
    ortho = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if ortho > rotation_tol or np.linalg.det(R) <= 0:
        return PoseReading(None, False, name, f"the pose rotation is not a rotation (max |R^T R - I| = {ortho:.1e})")
    T[:3, :3] = tf.orthonormalize(R)
    if not connected:
        return PoseReading(T, False, "Disconnected", "the device is not connected")
    if not bool(pose.bPoseIsValid):
        return PoseReading(T, False, name, "OpenVR marks the pose invalid (bPoseIsValid false)")
    if result != RUNNING_OK:
        return PoseReading(T, False, name, f"tracking result is {name}, not Running_OK")
    return PoseReading(T, True, name, "")


@dataclass(frozen=True)
class DeviceInfo:
    index: int
    device_class: int
    serial: str


def list_devices(vr_system: Any, openvr: Any) -> list[DeviceInfo]:
    """Every tracked device slot in use: index, class and serial (``Prop_SerialNumber_String``)."""
    found = []
    for i in range(int(openvr.k_unMaxTrackedDeviceCount)):
        cls = int(vr_system.getTrackedDeviceClass(i))
        if cls == 0:  # TrackedDeviceClass_Invalid: no device in this slot
            continue
        serial = str(vr_system.getStringTrackedDeviceProperty(i, openvr.Prop_SerialNumber_String))
        found.append(DeviceInfo(i, cls, serial))
    return found


def class_name(device_class: int) -> str:
    return {v: k for k, v in DEVICE_CLASSES.items()}.get(device_class, f"class {device_class}")


def select_device(devices: list[DeviceInfo], serial: str | None, device_class: str) -> DeviceInfo | str:
    """The device to follow, or a sentence saying why none (or several) match."""
    wanted = DEVICE_CLASSES.get(device_class)
    candidates = [d for d in devices if wanted is None or d.device_class == wanted]
    listing = ", ".join(f"{d.serial} ({class_name(d.device_class)})" for d in devices) or "none"
    if serial is not None:
        match = [d for d in devices if d.serial == serial]
        if not match:
            return f"no OpenVR device with serial {serial!r} is connected (devices seen: {listing})"
        return match[0]
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        return f"no {device_class} is connected (devices seen: {listing}); switch it on and pair it in SteamVR"
    return f"{len(candidates)} {device_class}s are connected ({listing}): set the 'serial' parameter to choose one"
