"""Vive desk calibration as stages (seed 001): ``vive_desk_calibration`` and ``vive_to_desktop``.

``vive_desk_calibration`` (solver): inputs ``contact`` (PoseStamped ``T_desktop_tcp``: where the
fixture holds the TCP, in the desk frame; translation = contact point + TCP offset, rotation =
fixture orientation), ``tracker_pose`` (TrackerPose ``T_base_tracker`` in the base-station frame;
readings flagged invalid are left out) and ``solve``. Publishes the result and, when usable,
``T_base_desktop`` (tracker frame_id, e.g. ``lighthouse`` -> contact frame_id, e.g. ``desktop``) and
the tracker on the tool, ``T_tcp_tracker`` = ``T_tracker_tcp``^-1 (``tcp_frame`` -> ``tracker_frame``,
``tracker_calibrated``): the robot's ``tcp`` is on the tree under its base, and a sampled tracker
publishes no frame of its own (a streaming one publishes ``lighthouse -> <tracker_frame>``).

``vive_to_desktop`` (transform): the real-time conversion ``T_desktop_tcp = inv(T_base_desktop)
T_base_tracker T_tracker_tcp`` with the seed's representations. Inputs ``tracker_pose`` and
``calibration`` (a CalibrationResultMsg of kind ``vive_desk``: from ``vive_desk_calibration`` or
from ``calibration_file``). It refuses a degenerate or failed calibration (alarm, and it stops
converting until a usable one arrives); tracker poses that arrive before any calibration wait in a
bounded queue (``max_pending``). Outputs per valid tracker reading: ``pose`` (PoseStamped
``T_desktop_tcp`` in ``desktop_frame``, stamped like the reading) and ``representations`` (a JSON
Blob: ``si`` = matrix, position, quaternion xyzw, ZYX Euler roll/pitch/yaw, rotation vector and the
1-sigma of the pose in m / rad; ``human`` = the same in mm / degrees).
"""

from __future__ import annotations

import json
from collections import deque
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.messages import Blob, CalibrationResultMsg, PoseStamped, TrackerPose
from engine.stage import Stage, StageParams
from engine.transforms import inv
from plugins.calibration.inputs import vive_desk_data
from plugins.calibration.result import CalibrationResult
from plugins.calibration.stages.base import CalibrationStage, PairingParams
from plugins.calibration.vive_desk import DesktopTcpConverter, TrackerTcpPrior, ViveNoiseModel, calibrate_vive_desk
from plugins.params import PoseSpec


class ViveDeskCalibration(CalibrationStage):
    """Vive desk calibration: T_base_desktop and T_tracker_tcp from fixture contacts and tracker poses."""

    type_name = "vive_desk_calibration"
    KIND = "vive_desk"
    DATA_PORTS: ClassVar = {"contact": PoseStamped, "tracker_pose": TrackerPose}

    class Params(PairingParams):
        tracker_position_sigma_m: float = Field(0.5e-3, gt=0.0, description="tracker position noise per axis")
        tracker_rotation_sigma_deg: float = Field(0.1, gt=0.0)
        fixture_rotation_sigma_deg: float = Field(0.3, gt=0.0, description="scatter of the tool in the fixture")
        desk_point_sigma_m: float = Field(0.0, ge=0.0)
        prior_T_tracker_tcp: PoseSpec | None = Field(None, description="CAD / caliper T_tracker_tcp (seed method A)")
        prior_sigma_m: float = Field(1e-3, gt=0.0, description="1-sigma of the prior's lever arm")
        tracker_frame: str = "tracker_calibrated"
        tcp_frame: str = "tcp"

    def calibrate(self) -> tuple[CalibrationResult, list[str]]:
        p: ViveDeskCalibration.Params = self.params  # type: ignore[assignment]
        noise = ViveNoiseModel(
            tracker_position_sigma_m=p.tracker_position_sigma_m,
            tracker_rotation_sigma_rad=float(np.radians(p.tracker_rotation_sigma_deg)),
            fixture_rotation_sigma_rad=float(np.radians(p.fixture_rotation_sigma_deg)),
            desk_point_sigma_m=p.desk_point_sigma_m,
        )
        data, notes = vive_desk_data(*self.streams(), noise=noise, **self.pairing())
        prior = None if p.prior_T_tracker_tcp is None else TrackerTcpPrior(p.prior_T_tracker_tcp.T(), p.prior_sigma_m)
        return calibrate_vive_desk(data, prior=prior), notes

    def transforms(self, result: CalibrationResult) -> list[tuple[np.ndarray, str, str]]:
        p: ViveDeskCalibration.Params = self.params  # type: ignore[assignment]
        base, desk = self.frame_of("tracker_pose", "lighthouse"), self.frame_of("contact", "desktop")
        e = result.estimate
        return [(e["T_base_desktop"], base, desk), (inv(e["T_tracker_tcp"]), p.tcp_frame, p.tracker_frame)]


class ViveToDesktop(Stage):
    """Real-time T_desktop_tcp from tracker poses with a usable Vive desk calibration (seed 001 output formats)."""

    type_name = "vive_to_desktop"
    role = "transform"
    inputs: ClassVar = {"tracker_pose": TrackerPose, "calibration": CalibrationResultMsg}
    outputs: ClassVar = {"pose": PoseStamped, "representations": Blob}

    class Params(StageParams):
        desktop_frame: str = "desktop"
        include_tracker_noise: bool = Field(True, description="add the live tracker jitter to the pose covariance")
        max_pending: int = Field(10_000, ge=0, description="tracker poses kept while no calibration is known")

    def setup(self) -> None:
        p: ViveToDesktop.Params = self.params  # type: ignore[assignment]
        self.converter: DesktopTcpConverter | None = None
        self.pending: deque[TrackerPose] = deque(maxlen=p.max_pending or None)
        self.refused = False
        self.dropped = 0
        self.invalid = 0

    def on_message(self, port: str, msg: Any) -> None:
        if port == "calibration":
            self._calibration(msg)
        elif self.converter is not None:
            self._convert(msg)
        elif self.refused:
            self.dropped += 1
        else:
            p: ViveToDesktop.Params = self.params  # type: ignore[assignment]
            if p.max_pending == 0 or len(self.pending) == p.max_pending:
                self.dropped += 1
            if p.max_pending:
                self.pending.append(msg)

    def _calibration(self, msg: CalibrationResultMsg) -> None:
        p: ViveToDesktop.Params = self.params  # type: ignore[assignment]
        try:
            result = CalibrationResult.from_dict(json.loads(msg.result_json))
            self.converter = DesktopTcpConverter.from_result(result, include_tracker_noise=p.include_tracker_noise)
        except (ValueError, KeyError) as exc:
            self.converter, self.refused = None, True
            self.ctx.event(
                "alarm",
                "calibration_refused",
                f"Vive desk calibration refused, no poses converted until a usable one arrives: {exc}",
                verdict=msg.verdict,
            )
            return
        self.refused = False
        self.ctx.event("info", "calibration_applied", f"Vive desk calibration applied (verdict {result.verdict})")
        while self.pending:
            self._convert(self.pending.popleft())

    def _convert(self, msg: TrackerPose) -> None:
        assert self.converter is not None
        p: ViveToDesktop.Params = self.params  # type: ignore[assignment]
        if not msg.valid:
            self.invalid += 1
            if self.invalid == 1:
                self.ctx.event("warning", "tracking_lost", f"tracker reading invalid ({msg.tracking_result}): skipped")
            return
        pose = self.converter.convert(msg.T)
        self.ctx.publish("pose", PoseStamped(T=pose.T_desktop_tcp, frame_id=p.desktop_frame, stamp_ns=msg.stamp_ns))
        doc = {"serial": msg.serial, "si": pose.to_dict(), "human": pose.to_dict(human=True)}
        data = json.dumps(doc, sort_keys=True).encode()
        self.ctx.publish(
            "representations",
            Blob(data=data, content_type="application/json", frame_id=p.desktop_frame, stamp_ns=msg.stamp_ns),
        )

    def finish(self) -> None:
        if self.pending or self.dropped:
            self.ctx.event(
                "warning",
                "not_converted",
                f"{len(self.pending) + self.dropped} tracker pose(s) not converted: no usable calibration"
                + (f"; {self.invalid} invalid reading(s) skipped" if self.invalid else ""),
            )
