"""``vive_tracker``: a Vive tracker (or any OpenVR device) through pyopenvr, with the tracker contract.

Output ``pose`` (TrackerPose, T_lighthouse_tracker) at ``stream_hz`` and service ``sample`` (a fresh
reading), as ``sim_tracker``. The "lighthouse" frame is the OpenVR tracking universe chosen with
``universe`` (raw by default, see :mod:`plugins.devices.openvr_poses` for axes and units: metres,
+y up, -z forward). Each reading carries ``valid`` (connected, ``bPoseIsValid``, ``Running_OK``, a
rigid matrix) and ``tracking_result`` (OpenVR's name, or ``Disconnected``); an event is raised when
tracking is lost or regained. Readings are stamped by the run's clock when they are read, not with
OpenVR's own timing (use ``predict_s`` to ask OpenVR for the pose a little ahead).

Frames (``frames``, for the 3D view): ``parent_frame -> frame_id`` (``T_parent_lighthouse``: where
the tracking universe sits in the cell; default identity in ``world``, i.e. not given) at set-up,
and with every published or sampled reading, that edge and ``frame_id -> tracker_frame`` (the
reading; left out when it is invalid). A sampled reading goes on ``frames`` only while the stream
runs: the engine ends a streaming stage's outputs when its stream ends (at once for ``stream_hz: 0``).

Lifecycle: ``openvr.init(VRApplication_Other)`` at set-up (SteamVR must be running), the device found
by serial (``Prop_SerialNumber_String``) within ``wait_for_device_s``, ``openvr.shutdown()`` at
teardown. The SDK (PyPI ``openvr``) is imported at set-up, not when vgr is imported.
"""

from __future__ import annotations

import threading
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from engine.messages import FrameTransforms, TrackerPose, Transform
from engine.stage import Stage, StageParams
from plugins.devices.openvr_poses import (
    UNIVERSES,
    DeviceInfo,
    PoseReading,
    list_devices,
    reading_from_pose,
    select_device,
)
from plugins.interfaces import TRACKER_OUTPUTS, TRACKER_SERVICES
from plugins.params import PoseSpec
from plugins.util.run_scoped_port import RunScopedPort
from plugins.util.sdk import import_sdk

RESCAN_INTERVAL_S = 1.0  # how often a lost device is looked up again


class ViveTrackerError(RuntimeError):
    """OpenVR could not be started or the device is not there; the message says what to check."""


def _init_hint(exc: BaseException) -> str:
    return (
        f"OpenVR could not start ({type(exc).__name__}: {exc}). Check: SteamVR is installed and has run once "
        "on this machine (it writes ~/.config/openvr/openvrpaths.vrpath), SteamVR is running, the base stations "
        "and the tracker are on and paired; a cell without a headset needs SteamVR configured not to require "
        "one (steamvr.vrsettings)"
    )


class ViveTrackerParams(StageParams):
    """Parameters of ``vive_tracker`` (units in names: s, Hz)."""

    serial: str | None = Field(None, description="device serial, e.g. LHR-0DC8A1B2; None = the only one connected")
    device_class: Literal["tracker", "controller", "hmd", "any"] = Field(
        "tracker", description="which devices qualify when no serial is given"
    )
    universe: Literal["raw", "standing", "seated"] = Field(
        "raw", description="OpenVR tracking universe the pose is expressed in (raw is not moved by room setup)"
    )
    stream_hz: float = Field(100.0, ge=0.0, le=1000.0, description="published readings per second; 0 = sample only")
    duration_s: float | None = Field(None, gt=0.0, description="stream this long, s; None = until the run stops")
    predict_s: float = Field(0.0, ge=0.0, le=0.1, description="ask OpenVR for the pose this far ahead, s")
    wait_for_device_s: float = Field(5.0, ge=0.0, description="at set-up, wait this long for the device, s")
    publish_invalid: bool = Field(True, description="publish invalid readings too (valid=false) instead of skipping")
    frame_id: str = Field("lighthouse", description="frame name of the tracking universe in messages")
    tracker_frame: str = Field("tracker", min_length=1, description="frame of the tracked device on frames")
    parent_frame: str = Field("world", min_length=1, description="frame the tracking universe is placed in")
    T_parent_lighthouse: PoseSpec = Field(
        default_factory=PoseSpec, description="the tracking universe in parent_frame, published on frames"
    )

    @model_validator(mode="after")
    def _distinct_frames(self) -> ViveTrackerParams:
        if len({self.parent_frame, self.frame_id, self.tracker_frame}) != 3:
            raise ValueError(
                f"parent_frame, frame_id and tracker_frame must differ, got "
                f"{self.parent_frame!r}, {self.frame_id!r}, {self.tracker_frame!r}"
            )
        return self


class ViveTracker(Stage):
    """Vive tracker via OpenVR (pyopenvr): streamed and sampled T_lighthouse_tracker with validity."""

    type_name = "vive_tracker"
    role = "sensor"
    services: ClassVar = TRACKER_SERVICES
    outputs: ClassVar = {**TRACKER_OUTPUTS, "frames": FrameTransforms}
    Params = ViveTrackerParams

    openvr: Any = None
    vr: Any = None

    def setup(self) -> None:
        p: ViveTrackerParams = self.params  # type: ignore[assignment]
        self._lock = threading.Lock()
        self._frames = RunScopedPort(self.ctx, "frames")  # published until the stream (run) ends
        self._last_valid: bool | None = None
        self._last_scan_s = -np.inf
        openvr = import_sdk("openvr", stage_type=self.type_name, extra="vive", package="openvr")
        try:
            self.vr = openvr.init(openvr.VRApplication_Other)
        except Exception as exc:
            raise ViveTrackerError(_init_hint(exc)) from exc
        self.openvr = openvr
        self._poses = (openvr.TrackedDevicePose_t * int(openvr.k_unMaxTrackedDeviceCount))()
        self._universe = UNIVERSES[p.universe]
        self.device = self._find_device(p.wait_for_device_s)
        self.ctx.event("info", "tracker_found", f"following {self.device.serial} (OpenVR index {self.device.index})")
        self._publish_frames(None)

    def _find_device(self, wait_s: float) -> DeviceInfo:
        p: ViveTrackerParams = self.params  # type: ignore[assignment]
        deadline = self.ctx.clock.now_s() + wait_s
        while True:
            choice = select_device(list_devices(self.vr, self.openvr), p.serial, p.device_class)
            if isinstance(choice, DeviceInfo):
                return choice
            if self.ctx.clock.now_s() >= deadline or not self.ctx.sleep(0.1):
                raise ViveTrackerError(f"{choice} (waited {wait_s:g} s)")

    def teardown(self) -> None:
        if self.openvr is not None:
            openvr, self.openvr, self.vr = self.openvr, None, None
            openvr.shutdown()

    # -- readings ------------------------------------------------------------------------------
    def _read(self) -> PoseReading:
        self.vr.getDeviceToAbsoluteTrackingPose(self._universe, self.params.predict_s, self._poses)  # type: ignore[attr-defined]
        reading = reading_from_pose(self._poses[self.device.index])
        if reading.tracking_result == "Disconnected":
            self._rescan()
        return reading

    def _rescan(self) -> None:
        """A device that disconnects and comes back may get another index: look it up again."""
        now = self.ctx.clock.now_s()
        if now - self._last_scan_s < RESCAN_INTERVAL_S:
            return
        self._last_scan_s = now
        same = [d for d in list_devices(self.vr, self.openvr) if d.serial == self.device.serial]
        connected = [d for d in same if self._poses[d.index].bDeviceIsConnected]
        if connected and connected[0].index != self.device.index:
            self.device = connected[0]
            self.ctx.event("info", "tracker_moved", f"{self.device.serial} is now OpenVR index {self.device.index}")

    def _message(self) -> TrackerPose:
        p: ViveTrackerParams = self.params  # type: ignore[assignment]
        with self._lock:  # the stream thread and the sample service share the device and the state
            reading = self._read()
            changed, self._last_valid = reading.valid != self._last_valid, reading.valid
        if changed and reading.valid:
            self.ctx.event("info", "tracking_ok", f"{self.device.serial}: tracking")
        elif changed:
            self.ctx.event(
                "warning",
                "tracking_lost",
                f"{self.device.serial}: {reading.reason}",
                tracking_result=reading.tracking_result,
            )
        return TrackerPose(
            serial=self.device.serial,
            frame_id=p.frame_id,
            T=reading.T if reading.T is not None else np.eye(4),
            valid=reading.valid,
            tracking_result=reading.tracking_result,
        )

    def _publish_frames(self, reading: TrackerPose | None) -> None:
        p: ViveTrackerParams = self.params  # type: ignore[assignment]
        now = self.ctx.clock.now_ns()
        tree = [
            Transform(frame_id=p.parent_frame, child_frame_id=p.frame_id, T=p.T_parent_lighthouse.T(), stamp_ns=now)
        ]
        if reading is not None and reading.valid:
            tree.append(Transform(frame_id=p.frame_id, child_frame_id=p.tracker_frame, T=reading.T, stamp_ns=now))
        self._frames.publish(FrameTransforms(stamp_ns=now, transforms=tree))

    def on_request(self, service: str, request: Any) -> TrackerPose:
        msg = self._message()
        self._publish_frames(msg)
        return msg

    def run(self) -> None:
        self._frames.run(self._stream)

    def _stream(self) -> None:
        p: ViveTrackerParams = self.params  # type: ignore[assignment]
        if p.stream_hz <= 0:
            return
        n = None if p.duration_s is None else max(1, round(p.duration_s * p.stream_hz))
        t0_ns = self.ctx.clock.now_ns()
        i = 0
        while (n is None or i < n) and not self.ctx.stopping:
            msg = self._message()
            if msg.valid or p.publish_invalid:
                self.ctx.publish("pose", msg)
                self._publish_frames(msg)
            i += 1
            # sleep to the next tick of a fixed grid, so the time spent reading does not lower the rate
            next_ns = t0_ns + round(i * 1e9 / p.stream_hz)
            if not self.ctx.sleep(max(0, next_ns - self.ctx.clock.now_ns()) / 1e9):
                return
