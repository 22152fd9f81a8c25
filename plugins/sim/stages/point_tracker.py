"""``sim_point_tracker``: a simulated point-measuring instrument (role sensor).

Plays two devices of the calibration cells:

* a **laser tracker** measuring a reflector on the tool (kinematic calibration, seed 003): the point
  ``point_tcp_m`` of the robot's TCP frame, in the tracker's own frame ``T_world_instrument``, with
  Gaussian noise per axis (default 0.05 mm, a laser tracker's class);
* a **camera that sees the tool tip** (TCP calibration by camera, seed 002): the same measurement
  with the camera's pose and noise (e.g. 0.3 mm, more along the optical axis). The depth camera of
  ``sim_camera`` renders surfaces, not points; this stage stands in for a tip detector on its images.

Where the TCP truly is comes from the simulated robot (client ``robot`` -> ``sim_robot.truth``, so
robot effects such as DH errors show up in the measurement). Service ``measure`` (Request ->
PoseStamped): one reading now, stamped with the instrument's time, frame ``frame_id``. The pose's
translation is the measured point; its rotation is the identity unless ``measure_orientation``
(then the measured tool orientation, with ``rotation_sigma_deg`` noise: a 6-DoF tracker probe).
Every reading is also published on ``point`` and the noise-free one on ``truth/point``. ``frames``
(for the 3D view) carries ``world -> frame_id`` (``T_world_instrument``), at set-up and with every
reading.
"""

from __future__ import annotations

from typing import ClassVar, cast

import numpy as np
from pydantic import Field

from engine.messages import FrameTransforms, PoseStamped, Request, RobotReply, Transform
from engine.stage import ServiceSpec, Stage, StageParams
from engine.transforms import T_from_Rt, exp_so3, inv
from plugins.params import PoseSpec

POINT_MEASURE = ServiceSpec(Request, PoseStamped)  # what a stage that uses the instrument declares


class SimPointTracker(Stage):
    """Simulated point instrument (laser tracker, or a camera seeing a tool tip): noisy TCP point."""

    type_name = "sim_point_tracker"
    role = "sensor"
    services: ClassVar = {
        "measure": ServiceSpec(Request, PoseStamped, "one reading: the tool point in the instrument frame")
    }
    outputs: ClassVar = {"point": PoseStamped, "frames": FrameTransforms, "truth/point": PoseStamped}
    uses: ClassVar = {"robot": ServiceSpec(Request, RobotReply, "sim_robot.truth: where the TCP truly is")}

    class Params(StageParams):
        T_world_instrument: PoseSpec = Field(
            default_factory=lambda: PoseSpec(xyz_m=(1.5, 0.3, 0.2), rpy_deg=(0.0, 0.0, 115.0)),
            description="the instrument frame in the world",
        )
        point_tcp_m: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="measured point, TCP frame")
        sigma_m: tuple[float, float, float] = Field(
            (5e-5, 5e-5, 5e-5), description="noise per instrument axis (m, 1 sigma)"
        )
        measure_orientation: bool = Field(False, description="also measure the tool orientation (6-DoF probe)")
        rotation_sigma_deg: float = Field(0.005, ge=0.0)
        frame_id: str = Field("tracker", description="name of the instrument frame on the messages")

    def setup(self) -> None:
        p: SimPointTracker.Params = self.params  # type: ignore[assignment]
        if any(s < 0 or not np.isfinite(s) for s in p.sigma_m):
            raise ValueError(f"sigma_m must be finite and >= 0, got {p.sigma_m}")
        self.T_instr_world = inv(p.T_world_instrument.T())
        self.point = np.asarray(p.point_tcp_m, dtype=float)
        self._publish_frames(self.ctx.clock.now_ns())

    def _publish_frames(self, stamp_ns: int) -> None:
        p: SimPointTracker.Params = self.params  # type: ignore[assignment]
        if p.frame_id == "world":
            return  # the instrument frame is the world itself
        edge = Transform(frame_id="world", child_frame_id=p.frame_id, T=p.T_world_instrument.T(), stamp_ns=stamp_ns)
        self.ctx.publish("frames", FrameTransforms(stamp_ns=stamp_ns, transforms=[edge]))

    def _reading(self) -> tuple[PoseStamped, PoseStamped]:
        p: SimPointTracker.Params = self.params  # type: ignore[assignment]
        reply = cast(RobotReply, self.ctx.call("robot", Request(command="truth")))
        if not reply.ok or reply.T is None:
            raise RuntimeError(f"the simulated robot did not give its TCP pose: {reply.error}")
        T_instr_tcp = self.T_instr_world @ np.asarray(reply.T, dtype=float)
        R_true = T_instr_tcp[:3, :3] if p.measure_orientation else np.eye(3)
        p_true = T_instr_tcp[:3, :3] @ self.point + T_instr_tcp[:3, 3]
        rng = self.ctx.rng
        p_meas = p_true + rng.normal(0.0, 1.0, 3) * np.asarray(p.sigma_m)
        R_meas = R_true
        if p.measure_orientation:
            R_meas = exp_so3(rng.normal(0.0, np.radians(p.rotation_sigma_deg), 3)) @ R_true
        stamp = self.ctx.clock.now_ns()
        meas = PoseStamped(T=T_from_Rt(R_meas, p_meas), frame_id=p.frame_id, stamp_ns=stamp)
        truth = PoseStamped(T=T_from_Rt(R_true, p_true), frame_id=p.frame_id, stamp_ns=stamp)
        return meas, truth

    def on_request(self, service: str, request: Request) -> PoseStamped:  # type: ignore[override]
        meas, truth = self._reading()
        self._publish_frames(meas.stamp_ns)
        self.ctx.publish("point", meas)
        self.ctx.publish("truth/point", truth)
        return meas
