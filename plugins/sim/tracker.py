"""Simulated HTC Vive tracker: the tracker's pose in the base-station (lighthouse) frame over time.

This module owns the sensor model of a Vive tracker as vgr sees it through OpenVR: a stream of
``T_lighthouse_tracker`` poses with time stamps, sequence numbers and a validity flag.

* **Rate.** One sample every ``1 / rate_hz`` seconds, default 250 Hz.  SteamVR's pose is the output of
  an IMU-driven filter corrected by the lighthouse sweeps, so the rate an application sees is its own
  polling rate; 250 Hz is a typical choice for a tracker polled outside a render loop (the brief asks
  250 Hz for a Vive Tracker 3.0).  Set ``rate_hz`` to whatever the real adapter polls at.
* **Jitter.** White Gaussian noise, isotropic in position (default sigma 0.3 mm) and as a rotation
  vector in the tracker frame (default 0.02 deg).  Static jitter of Lighthouse tracking is reported
  in the 0.3-1 mm range: O. Kreylos, "Lighthouse tracking examined" (doc-ok.org, 2016) measured
  ~0.3 mm RMS with two base stations; Niehorster, Li & Lappe, i-Perception 8(3) 2017 report sub-mm
  precision of a static Vive; Bauer, Lienhart & Jost, Sensors 21:1622 (2021) find mm-level
  repeatability but cm-level *systematic* errors (the latter are not modelled here: they belong to a
  desk/lighthouse calibration effect).  The orientation jitter is an assumption of the same order
  (0.3 mm over a ~50 mm sensor constellation ~ 0.3 deg worst case; the filtered output is far
  smoother, so 0.02 deg is used).  Set both to zero for an ideal tracker.
* **Effects** (:class:`~plugins.sim.sensor_effects.TrackerEffects`, off by default): latency (the pose
  reported at ``t`` is the true pose at ``t - latency_s``), extra noise and extra dropouts.  A dropout
  gives a sample with ``valid=False`` and no pose, as OpenVR's ``bPoseIsValid`` does; a trajectory
  that returns ``None`` (tracker occluded / out of view) does the same.

The trajectory is any function ``t (s) -> T_lighthouse_tracker_true (4x4)``, e.g. a robot's TCP pose
composed with the tracker mount, so the tracker can follow a simulated robot.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from engine.transforms import T_from_rotvec, as_transform
from plugins.sim.sensor_effects import TrackerEffects

__all__ = ["SimulatedViveTracker", "TrackerSample", "TrackerTruth", "ViveTrackerModel"]

Trajectory = Callable[[float], np.ndarray | None]


@dataclass(frozen=True)
class ViveTrackerModel:
    """Rate and jitter of a Vive tracker (see the module docstring for the sources)."""

    rate_hz: float = 250.0
    position_sigma_m: float = 0.0003
    rotation_sigma_rad: float = math.radians(0.02)

    def __post_init__(self) -> None:
        vals = (self.rate_hz, self.position_sigma_m, self.rotation_sigma_rad)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"tracker model parameters must be finite, got {self}")
        if self.rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, got {self.rate_hz}")
        if self.position_sigma_m < 0 or self.rotation_sigma_rad < 0:
            raise ValueError("tracker jitter sigmas must be non-negative")

    @classmethod
    def ideal(cls, rate_hz: float = 250.0) -> ViveTrackerModel:
        return cls(rate_hz=rate_hz, position_sigma_m=0.0, rotation_sigma_rad=0.0)


@dataclass
class TrackerSample:
    """What the tracker reports: a stamped pose in the lighthouse frame, or an invalid sample."""

    stamp_ns: int
    seq: int
    valid: bool
    T_lighthouse_tracker: np.ndarray | None  # None when not valid


@dataclass
class TrackerTruth:
    """The truth behind one sample (tests only)."""

    stamp_s: float
    measured_at_s: float  # stamp_s - latency
    T_lighthouse_tracker_at_stamp: np.ndarray | None
    T_lighthouse_tracker_measured: np.ndarray | None  # the true pose the sample was made from
    dropped: bool


class SimulatedViveTracker:
    """Samples a trajectory like a Vive tracker: rate, jitter, latency, dropouts."""

    def __init__(
        self,
        trajectory: Trajectory,
        model: ViveTrackerModel | None = None,
        effects: TrackerEffects | None = None,
    ) -> None:
        if not callable(trajectory):
            raise TypeError("trajectory must be a function t (s) -> T_lighthouse_tracker (4x4)")
        self.trajectory = trajectory
        self.model = model if model is not None else ViveTrackerModel()
        self.effects = effects if effects is not None else TrackerEffects()
        self._seq = 0

    def _true_pose(self, t: float) -> np.ndarray | None:
        T = self.trajectory(t)
        return None if T is None else as_transform(T, name=f"trajectory({t:.6f})")

    def sample(self, t: float, rng: np.random.Generator) -> tuple[TrackerSample, TrackerTruth]:
        """The sample the tracker reports at time ``t`` (s), and its truth."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator")
        if not math.isfinite(t):
            raise ValueError(f"sample time must be finite, got {t}")
        measured_at = t - self.effects.latency_s
        T_meas_true = self._true_pose(measured_at)
        # the draws are made for every sample, valid or not, so that one dropout does not shift the
        # noise of all later samples
        n_pos = rng.standard_normal(3)
        n_rot = rng.standard_normal(3)
        u = rng.random()
        pos_sigma = math.hypot(self.model.position_sigma_m, self.effects.extra_position_sigma_m)
        rot_sigma = math.hypot(self.model.rotation_sigma_rad, self.effects.extra_rotation_sigma_rad)
        dropped = T_meas_true is None or u < self.effects.dropout_prob
        T_reported = None
        if not dropped:
            T_reported = T_meas_true @ T_from_rotvec(rot_sigma * n_rot)
            T_reported[:3, 3] += pos_sigma * n_pos
        sample = TrackerSample(
            stamp_ns=round(t * 1e9), seq=self._seq, valid=not dropped, T_lighthouse_tracker=T_reported
        )
        self._seq += 1
        truth = TrackerTruth(
            stamp_s=t,
            measured_at_s=measured_at,
            T_lighthouse_tracker_at_stamp=self._true_pose(t),
            T_lighthouse_tracker_measured=T_meas_true,
            dropped=dropped,
        )
        return sample, truth

    def stream(
        self, t_start: float, duration_s: float, rng: np.random.Generator
    ) -> list[tuple[TrackerSample, TrackerTruth]]:
        """Samples at the model's rate over ``[t_start, t_start + duration_s)``."""
        if not (math.isfinite(t_start) and math.isfinite(duration_s)) or duration_s < 0:
            raise ValueError(f"need a finite start and a non-negative duration, got {t_start}, {duration_s}")
        n = math.ceil(duration_s * self.model.rate_hz - 1e-9)
        return [self.sample(t_start + k / self.model.rate_hz, rng) for k in range(n)]
