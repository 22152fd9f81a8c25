"""The sensor side of the simulated cell: parts with poses, the camera mount, the Vive tracker, effects.

This module ties the workpieces, the depth camera, the tracker and the sensor-side effects into one
description a stage can wrap: ``SimCell.capture(T_world_tcp, rng) -> (DepthCapture, CaptureTruth)``,
``SimCell.tracker(...)`` and ``SimCell.frames(...)`` for the 3D view.

Frames (names used in :meth:`SimCell.frames`): ``world``; ``base`` (robot base, ``T_world_base``);
``tcp`` (from the robot); ``camera`` (child of ``tcp`` for eye-in-hand, of ``world`` for eye-to-hand);
one frame per part, named after the part, child of ``world`` or ``tcp``; ``lighthouse`` (child of
``world``) and ``tracker`` (child of ``lighthouse``, the tracker on the TCP).

Nominal versus true: the cell holds the *nominal* camera mount and part poses (what the solvers are
told); the effects make the *true* ones, which the renderer uses.  ``frames(truth=False)`` gives
the nominal tree, ``frames(truth=True)`` the true one (for ``truth/`` keys and tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from engine.transforms import as_transform, inv
from plugins.sim.camera import DepthCameraModel, DepthCapture, RenderTruth
from plugins.sim.sensor_effects import SensorEffects
from plugins.sim.tracker import SimulatedViveTracker, ViveTrackerModel
from plugins.util.workpieces import Workpiece

__all__ = ["CameraMount", "CaptureTruth", "Frame", "PartPlacement", "SimCell", "TrackerMount"]

PoseOrTrajectory = np.ndarray | Callable[[float], np.ndarray] | None


@dataclass(frozen=True)
class Frame:
    """One edge of the frame tree: ``T_parent_child`` (maps child points into the parent)."""

    parent: str
    child: str
    T_parent_child: np.ndarray


@dataclass
class PartPlacement:
    """A workpiece and its nominal pose in its parent frame (``world``, or ``tcp`` when gripped)."""

    name: str
    workpiece: Workpiece
    T_parent_part: np.ndarray
    parent: Literal["world", "tcp"] = "world"

    def __post_init__(self) -> None:
        if self.parent not in ("world", "tcp"):
            raise ValueError(f"part {self.name!r}: parent must be 'world' or 'tcp', got {self.parent!r}")
        self.T_parent_part = as_transform(self.T_parent_part, name=f"T_{self.parent}_{self.name}")


@dataclass
class CameraMount:
    """Eye-in-hand (``T_tcp_cam``, camera on the flange) or eye-to-hand (``T_world_cam``, fixed)."""

    kind: Literal["eye_in_hand", "eye_to_hand"]
    T_mount_cam: np.ndarray  # nominal T_tcp_cam or T_world_cam

    def __post_init__(self) -> None:
        if self.kind not in ("eye_in_hand", "eye_to_hand"):
            raise ValueError(f"camera mount kind must be eye_in_hand or eye_to_hand, got {self.kind!r}")
        self.T_mount_cam = as_transform(self.T_mount_cam, name="camera mount transform")

    @classmethod
    def eye_in_hand(cls, T_tcp_cam: np.ndarray) -> CameraMount:
        return cls("eye_in_hand", T_tcp_cam)

    @classmethod
    def eye_to_hand(cls, T_world_cam: np.ndarray) -> CameraMount:
        return cls("eye_to_hand", T_world_cam)

    @property
    def parent(self) -> str:
        return "tcp" if self.kind == "eye_in_hand" else "world"


@dataclass
class TrackerMount:
    """A Vive tracker on the TCP (``T_tcp_tracker``) seen by a base station at ``T_world_lighthouse``."""

    T_world_lighthouse: np.ndarray
    T_tcp_tracker: np.ndarray
    model: ViveTrackerModel = field(default_factory=ViveTrackerModel)

    def __post_init__(self) -> None:
        self.T_world_lighthouse = as_transform(self.T_world_lighthouse, name="T_world_lighthouse")
        self.T_tcp_tracker = as_transform(self.T_tcp_tracker, name="T_tcp_tracker")


@dataclass
class CaptureTruth:
    """Everything true about one capture (tests and ``truth/`` keys only, never solvers)."""

    stamp_s: float
    exposure_s: float  # stamp_s - camera latency: when the image was really taken
    T_world_tcp: np.ndarray | None  # at exposure
    T_world_cam: np.ndarray  # true, at exposure
    T_world_cam_nominal: np.ndarray  # what the solver believes, from the TCP pose at the stamp
    T_world_parts: dict[str, np.ndarray]  # true, at exposure
    T_world_parts_nominal: dict[str, np.ndarray]  # nominal, from the TCP pose at the stamp
    T_cam_parts: dict[str, np.ndarray]  # true part poses in the true camera frame
    render: RenderTruth  # per-point truth; render.part_index indexes part_names
    part_names: list[str]


def _pose_at(T_world_tcp: PoseOrTrajectory, t: float) -> np.ndarray | None:
    if T_world_tcp is None:
        return None
    T = T_world_tcp(t) if callable(T_world_tcp) else T_world_tcp
    return as_transform(T, name="T_world_tcp")


class SimCell:
    """Parts, camera (with its mount), optional tracker and sensor-side effects of one cell."""

    def __init__(
        self,
        camera: DepthCameraModel,
        mount: CameraMount,
        parts: Sequence[PartPlacement],
        effects: SensorEffects | None = None,
        T_world_base: np.ndarray | None = None,
        tracker: TrackerMount | None = None,
    ) -> None:
        if not isinstance(camera, DepthCameraModel):
            raise TypeError("camera must be a DepthCameraModel")
        if not isinstance(mount, CameraMount):
            raise TypeError("mount must be a CameraMount")
        names = [p.name for p in parts]
        if len(set(names)) != len(names):
            raise ValueError(f"part names must be unique, got {names}")
        self.camera = camera
        self.mount = mount
        self.parts = list(parts)
        self.effects = effects if effects is not None else SensorEffects()
        unknown = set(self.effects.placement) - set(names)
        if unknown:
            raise ValueError(f"placement offsets for unknown parts {sorted(unknown)}; parts: {names}")
        self.T_world_base = as_transform(np.eye(4) if T_world_base is None else T_world_base, name="T_world_base")
        self.tracker_mount = tracker
        noise = self.effects.camera.apply_to_noise(camera.noise)
        self._true_camera = DepthCameraModel(camera.intrinsics, noise, camera.min_range_m, camera.max_range_m)

    # ------------------------------------------------------------------ poses

    def _needs_tcp(self) -> bool:
        return self.mount.kind == "eye_in_hand" or any(p.parent == "tcp" for p in self.parts)

    def camera_pose(self, T_world_tcp: np.ndarray | None, truth: bool) -> np.ndarray:
        """T_world_cam, nominal or true (with the hand-eye error), for a TCP pose."""
        T_mount = self.mount.T_mount_cam
        if truth:
            T_mount = self.effects.camera.hand_eye_error.apply(T_mount)
        if self.mount.kind == "eye_to_hand":
            return T_mount
        if T_world_tcp is None:
            raise ValueError("an eye-in-hand camera needs the TCP pose")
        return T_world_tcp @ T_mount

    def part_pose(self, part: PartPlacement, T_world_tcp: np.ndarray | None, truth: bool) -> np.ndarray:
        """T_world_part, nominal or true (with its placement offset), for a TCP pose."""
        T = self.effects.placement_of(part.name).apply(part.T_parent_part) if truth else part.T_parent_part
        if part.parent == "world":
            return T
        if T_world_tcp is None:
            raise ValueError(f"part {part.name!r} is held by the TCP: the TCP pose is needed")
        return T_world_tcp @ T

    # ------------------------------------------------------------------ sensors

    def capture(
        self, T_world_tcp: PoseOrTrajectory, rng: np.random.Generator, t: float = 0.0
    ) -> tuple[DepthCapture, CaptureTruth]:
        """A depth frame stamped ``t`` (s) and its truth.

        ``T_world_tcp`` is the robot's TCP pose (4x4), or a function of time when the robot moves
        (needed for the camera latency effect to show), or ``None`` for an eye-to-hand camera with
        no part in the gripper.  With latency ``L`` the scene is rendered at ``t - L``.
        """
        if not math.isfinite(t):
            raise ValueError(f"capture time must be finite, got {t}")
        if T_world_tcp is None and self._needs_tcp():
            raise ValueError("this cell needs the TCP pose (eye-in-hand camera or a part in the gripper)")
        exposure = t - self.effects.camera.latency_s
        tcp_exposure = _pose_at(T_world_tcp, exposure)
        tcp_stamp = _pose_at(T_world_tcp, t)
        T_world_cam = self.camera_pose(tcp_exposure, truth=True)
        T_world_parts = {p.name: self.part_pose(p, tcp_exposure, truth=True) for p in self.parts}
        capture, render_truth = self._true_camera.render_with_truth(
            [(p.workpiece, T_world_parts[p.name]) for p in self.parts],
            T_world_cam,
            rng,
            stamp_ns=round(t * 1e9),
        )
        T_cam_world = inv(T_world_cam)
        truth = CaptureTruth(
            stamp_s=t,
            exposure_s=exposure,
            T_world_tcp=tcp_exposure,
            T_world_cam=T_world_cam,
            T_world_cam_nominal=self.camera_pose(tcp_stamp, truth=False),
            T_world_parts=T_world_parts,
            T_world_parts_nominal={p.name: self.part_pose(p, tcp_stamp, truth=False) for p in self.parts},
            T_cam_parts={k: T_cam_world @ v for k, v in T_world_parts.items()},
            render=render_truth,
            part_names=[p.name for p in self.parts],
        )
        return capture, truth

    def tracker(
        self, T_world_tcp: Callable[[float], np.ndarray | None], with_effects: bool = True
    ) -> SimulatedViveTracker:
        """A simulated Vive tracker that follows the TCP trajectory ``t -> T_world_tcp``.

        The tracker reports ``T_lighthouse_tracker = inv(T_world_lighthouse) @ T_world_tcp(t) @
        T_tcp_tracker``; a trajectory returning ``None`` means the tracker is not seen.
        ``with_effects=False`` leaves the cell's tracker effects (latency, extra noise) out.
        """
        if self.tracker_mount is None:
            raise ValueError("this cell has no tracker (give SimCell a TrackerMount)")
        if not callable(T_world_tcp):
            raise TypeError("the tracker needs the TCP trajectory as a function of time")
        m = self.tracker_mount
        T_lh_world = inv(m.T_world_lighthouse)

        def trajectory(t: float) -> np.ndarray | None:
            T = T_world_tcp(t)
            return None if T is None else T_lh_world @ as_transform(T, name="T_world_tcp") @ m.T_tcp_tracker

        effects = self.effects.tracker if with_effects else None
        return SimulatedViveTracker(trajectory, m.model, effects)

    # ------------------------------------------------------------------ 3D view

    def frames(self, T_world_tcp: PoseOrTrajectory, t: float = 0.0, truth: bool = False) -> list[Frame]:
        """The cell's frame tree at time ``t``: nominal (default) or true poses."""
        tcp = _pose_at(T_world_tcp, t)
        out = [Frame("world", "base", self.T_world_base.copy())]
        if tcp is not None:
            out.append(Frame("base", "tcp", inv(self.T_world_base) @ tcp))
        if self.mount.kind == "eye_to_hand" or tcp is not None:
            T_world_cam = self.camera_pose(tcp, truth)
            if self.mount.kind == "eye_in_hand":
                out.append(Frame("tcp", "camera", inv(tcp) @ T_world_cam))
            else:
                out.append(Frame("world", "camera", T_world_cam))
        for p in self.parts:
            if p.parent == "tcp" and tcp is None:
                continue
            T_world_part = self.part_pose(p, tcp, truth)
            T_parent = np.eye(4) if p.parent == "world" else tcp
            out.append(Frame(p.parent, p.name, inv(T_parent) @ T_world_part))
        if self.tracker_mount is not None:
            m = self.tracker_mount
            out.append(Frame("world", "lighthouse", m.T_world_lighthouse.copy()))
            if tcp is not None:
                out.append(Frame("lighthouse", "tracker", inv(m.T_world_lighthouse) @ tcp @ m.T_tcp_tracker))
        return out
