"""``sim_tracker``: the simulated Vive tracker as a sensor stage (tracker contract + ground truth).

The tracker sits on the TCP (``T_tcp_tracker``) and is seen by a base station at
``T_world_lighthouse``. Where the TCP truly is comes from the simulated robot (client ``robot`` ->
``sim_robot.truth``), or from ``T_world_tcp`` when no robot is wired (a tracker held in a fixture).
``sample`` answers with one reading; with ``stream_hz > 0`` the stage also publishes readings at
that rate for ``duration_s`` (on the ``sim`` clock, do not combine streaming with other stages that
move time, e.g. a moving sim_robot: both would advance the one simulated clock).

Frames (``frames``, for the 3D view): ``world -> lighthouse`` (``T_world_lighthouse``) at set-up, and
with every reading, ``world -> lighthouse`` and ``lighthouse -> <tracker_frame>`` (the reported pose;
left out when the reading is invalid). A sampled reading goes on ``frames`` only while the stream
runs: the engine ends a streaming stage's outputs when its stream ends, at once for
``stream_hz: 0`` (such readings are in the recording as the service's replies only). As for
``sim_camera``'s mount, the base station's placement is the simulated cell's geometry: solvers
that estimate it (the Vive desk calibration) take the tracker readings, never ``frames``.
"""

from __future__ import annotations

import math
import threading
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.messages import FrameTransforms, PoseStamped, Request, RobotReply, TrackerPose, Transform
from engine.stage import ServiceSpec, Stage, StageParams
from engine.transforms import inv
from plugins.interfaces import TRACKER_OUTPUTS, TRACKER_SERVICES
from plugins.params import PoseSpec
from plugins.sim.sensor_effects import TrackerEffects
from plugins.sim.tracker import SimulatedViveTracker, ViveTrackerModel
from plugins.util.run_scoped_port import RunScopedPort


class SimTracker(Stage):
    """Simulated Vive tracker on the TCP: jitter, latency, dropouts; truth on truth/pose."""

    type_name = "sim_tracker"
    role = "sensor"
    services: ClassVar = TRACKER_SERVICES
    outputs: ClassVar = {**TRACKER_OUTPUTS, "frames": FrameTransforms, "truth/pose": PoseStamped}
    uses: ClassVar = {"robot": ServiceSpec(Request, RobotReply, "sim_robot.truth", optional=True)}

    class Params(StageParams):
        serial: str = "LHR-SIM00001"
        T_world_lighthouse: PoseSpec = Field(default_factory=lambda: PoseSpec(xyz_m=(1.5, 0.0, 2.0)))
        T_tcp_tracker: PoseSpec = Field(default_factory=PoseSpec)
        T_world_tcp: PoseSpec | None = Field(None, description="fixed TCP pose when no robot is wired")
        position_sigma_m: float = Field(0.0003, ge=0.0)
        rotation_sigma_deg: float = Field(0.02, ge=0.0)
        effects: dict[str, Any] = Field(default_factory=dict, description="tracker effects (latency_s, ...)")
        stream_hz: float = Field(0.0, ge=0.0, le=1000.0, description="0 = readings on request only")
        duration_s: float = Field(1.0, gt=0.0)
        tracker_frame: str = Field("tracker", min_length=1, description="frame of the tracker on frames")

    def setup(self) -> None:
        p: SimTracker.Params = self.params  # type: ignore[assignment]
        if p.tracker_frame in ("world", "lighthouse"):
            raise ValueError(f"tracker_frame must differ from 'world' and 'lighthouse', got {p.tracker_frame!r}")
        self._lock = threading.Lock()
        self._frames = RunScopedPort(self.ctx, "frames")  # published until the stream (run) ends
        self._tcp_now: np.ndarray | None = None
        self.T_lh_world = inv(p.T_world_lighthouse.T())
        self.T_tcp_tracker = p.T_tcp_tracker.T()
        model = ViveTrackerModel(
            rate_hz=max(p.stream_hz, 1.0),
            position_sigma_m=p.position_sigma_m,
            rotation_sigma_rad=math.radians(p.rotation_sigma_deg),
        )
        self.tracker = SimulatedViveTracker(self._true_lighthouse_tracker, model, TrackerEffects.from_dict(p.effects))
        self.T_world_lighthouse = p.T_world_lighthouse.T()
        self._publish_frames(None, self.ctx.clock.now_ns())

    def _tcp(self) -> np.ndarray | None:
        p: SimTracker.Params = self.params  # type: ignore[assignment]
        if p.T_world_tcp is not None:
            return p.T_world_tcp.T()
        reply = self.ctx.call("robot", Request(command="truth"))
        return reply.T if reply.ok else None

    def _true_lighthouse_tracker(self, t: float) -> np.ndarray | None:
        T = self._tcp_now
        return None if T is None else self.T_lh_world @ T @ self.T_tcp_tracker

    def _reading(self) -> tuple[TrackerPose, np.ndarray | None]:
        """One reading and the true pose at its stamp (the run loop and the service share the
        tracker's sequence and random stream, hence the lock)."""
        p: SimTracker.Params = self.params  # type: ignore[assignment]
        with self._lock:
            self._tcp_now = self._tcp()
            stamp_ns = self.ctx.clock.now_ns()
            sample, truth = self.tracker.sample(stamp_ns / 1_000_000_000, self.ctx.rng)
        T = sample.T_lighthouse_tracker
        self._publish_frames(T, stamp_ns)
        reading = TrackerPose(
            stamp_ns=stamp_ns,  # when it was sampled (unset, a reply takes its request's stamp)
            serial=p.serial,
            frame_id="lighthouse",
            T=T if T is not None else np.eye(4),
            valid=sample.valid,
            tracking_result="Running_OK" if sample.valid else "Running_OutOfRange",
        )
        return reading, truth.T_lighthouse_tracker_at_stamp

    def _publish_frames(self, T_lighthouse_tracker: np.ndarray | None, stamp_ns: int) -> None:
        self._frames.publish(FrameTransforms(stamp_ns=stamp_ns, transforms=self._tree(T_lighthouse_tracker, stamp_ns)))

    def _tree(self, T_lighthouse_tracker: np.ndarray | None, stamp_ns: int) -> list[Transform]:
        p: SimTracker.Params = self.params  # type: ignore[assignment]
        tree = [Transform(frame_id="world", child_frame_id="lighthouse", T=self.T_world_lighthouse, stamp_ns=stamp_ns)]
        if T_lighthouse_tracker is not None:
            tree.append(
                Transform(
                    frame_id="lighthouse", child_frame_id=p.tracker_frame, T=T_lighthouse_tracker, stamp_ns=stamp_ns
                )
            )
        return tree

    def on_request(self, service: str, request: Any) -> TrackerPose:
        return self._reading()[0]

    def run(self) -> None:
        self._frames.run(self._stream)

    def _stream(self) -> None:
        p: SimTracker.Params = self.params  # type: ignore[assignment]
        if p.stream_hz <= 0:
            return
        for _ in range(max(1, round(p.duration_s * p.stream_hz))):
            if self.ctx.stopping:
                return
            reading, truth = self._reading()
            self.ctx.publish("pose", reading)
            if truth is not None:
                self.ctx.publish("truth/pose", PoseStamped(T=truth, frame_id="lighthouse", stamp_ns=reading.stamp_ns))
            if not self.ctx.sleep(1.0 / p.stream_hz):
                return
