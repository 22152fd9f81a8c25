"""``sim_camera``: the simulated depth camera as a sensor stage (camera contract + ground truth).

Wraps :class:`plugins.sim.cell.SimCell`. On ``capture`` it asks the simulated robot (client ``robot``,
wired to ``sim_robot.truth``) where the TCP truly is when the camera is on the flange or a part is in
the gripper, renders the scene with the noise model and the sensor effects (depth scale/bias, latency,
hand-eye error, placement offsets), and replies with the cloud in the camera frame. With a calibration
``board`` fixed in the cell (a spec string, :mod:`plugins.sim.board`) it renders the board's intensity
image too (lens distortion ``image.distortion``, blur, grey-level noise) and publishes it on ``image``
(mono8) with its camera model on ``image_info`` (CameraInfo with the distortion), both stamped like the
capture; the board's plate is a part of the depth scene and its frame (``board.name``) a child of
``world``. It also publishes the capture on ``cloud`` (every ``cloud_decimate``-th point: a lighter copy
for the recording's 3D view), the depth image, the intrinsics, the nominal frame tree, the workpiece
meshes (once) and, on ``truth/part_poses``, where the parts, the camera and the TCP truly were.

The camera's frame is ``frame_id`` (``camera`` by default) on every message and on ``frames``; give
each camera of a cell its own (e.g. ``fixed_camera``) so that the frame tree stays a tree. A part's
name is its frame, so it must not be one the cell already has (``world``, ``base``, ``tcp``, the
camera's). The true poses go under their own names, ``truth/<frame>`` (:func:`truth_frame`), as
children of ``world``: a 3D view reads every transform of a recording, and the same name with a
second parent (``world -> tcp`` beside ``base -> tcp``) or a second pose would not be one tree.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from engine.messages import (
    CameraInfo,
    FrameTransforms,
    Image,
    Mesh,
    PointCloud,
    Request,
    RobotReply,
    SceneMeshes,
    Transform,
)
from engine.stage import ServiceSpec, Stage, StageParams
from plugins.camera.board_spec import parse_board
from plugins.camera.pinhole import CameraModel
from plugins.devices.camera_output import thinned
from plugins.interfaces import CAMERA_OUTPUTS, CAMERA_SERVICES
from plugins.params import PoseSpec
from plugins.sim.board import BoardImager, board_workpiece
from plugins.sim.camera import DepthCameraModel, DepthNoiseModel, default_intrinsics
from plugins.sim.cell import CameraMount, PartPlacement, SimCell
from plugins.sim.sensor_effects import SensorEffects
from plugins.util.workpieces import make_workpiece

NOISE_PRESETS = ("noiseless", "industrial_structured_light", "realsense_d415", "kinect_v1")
TRUTH_PREFIX = "truth/"
CELL_FRAMES = ("world", "base", "tcp")  # the world and the robot's frames


def truth_frame(frame: str) -> str:
    """The name of *frame*'s true pose on ``truth/part_poses`` (a child of ``world``)."""
    return TRUTH_PREFIX + frame


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class IntrinsicsSpec(_Strict):
    width: int = Field(640, ge=8, le=8192)
    height: int = Field(480, ge=8, le=8192)
    fx: float = Field(0.0, ge=0.0, description="0 = the default ~60 deg horizontal field of view")
    fy: float = Field(0.0, ge=0.0)
    cx: float | None = None
    cy: float | None = None


class NoiseSpec(_Strict):
    preset: Literal["custom", "noiseless", "industrial_structured_light", "realsense_d415", "kinect_v1"] = "custom"
    sigma_const_m: float = Field(0.0001, ge=0.0, description="depth sigma = const + quad * z^2 (custom)")
    sigma_quad_per_m: float = Field(0.0, ge=0.0)
    grazing_dropout_deg: float = Field(80.0, gt=0.0, le=90.0)
    dropout_prob: float = Field(0.0, ge=0.0, lt=1.0)
    depth_unit_m: float = Field(0.0, ge=0.0, le=0.01, description="reported z rounded to this unit (any preset)")


class MountSpec(_Strict):
    kind: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand"
    pose: PoseSpec = Field(default_factory=PoseSpec, description="nominal T_tcp_cam (in hand) or T_world_cam")


class PartSpec(_Strict):
    name: str
    workpiece: str = Field(description="feature_part | planar_plate | symmetric_plate | base_plate")
    pose: PoseSpec = Field(default_factory=PoseSpec, description="nominal pose in its parent frame")
    parent: Literal["world", "tcp"] = "world"


class BoardSpecParams(_Strict):
    spec: str = Field(description="board spec, e.g. chessboard:9x6:25mm (docs/calibration_boards.md)")
    name: str = Field("board", min_length=1, description="the board's frame (its `target`), a child of world")
    pose: PoseSpec = Field(default_factory=PoseSpec, description="T_world_board: where the board lies")

    @field_validator("spec")
    @classmethod
    def _parses(cls, v: str) -> str:
        parse_board(v)
        return v


class ImageSpec(_Strict):
    distortion: tuple[float, float, float, float, float] = Field(
        (-0.08, 0.05, 0.0, 0.0, 0.0), description="lens distortion k1 k2 p1 p2 k3 of the intensity image"
    )
    noise_sigma: float = Field(2.0, ge=0.0, le=64.0, description="grey-level noise (of 255), 1 sigma")
    blur_sigma_px: float = Field(0.5, ge=0.0, le=10.0, description="defocus blur, Gaussian sigma in pixels")
    supersample: int = Field(3, ge=1, le=8, description="rays per pixel side (pixel area averaging)")


class SimCamera(Stage):
    """Simulated depth camera: renders the workpieces with noise, dropouts and injectable effects."""

    type_name = "sim_camera"
    role = "sensor"
    services: ClassVar = {
        **CAMERA_SERVICES,
        "place": ServiceSpec(
            Request, Request, "simulation: put part args.part at args.pose (a pose document) in the world"
        ),
        "fault": ServiceSpec(
            Request, Request, "simulation: the next args.captures captures fail (kind disconnect) or hang args.seconds"
        ),
    }
    outputs: ClassVar = {
        **CAMERA_OUTPUTS,
        "frames": FrameTransforms,
        "scene": SceneMeshes,
        "truth/part_poses": FrameTransforms,
        "image": Image,
        "image_info": CameraInfo,
    }
    uses: ClassVar = {
        "robot": ServiceSpec(Request, RobotReply, "sim_robot.truth: where the TCP truly is", optional=True)
    }

    class Params(StageParams):
        intrinsics: IntrinsicsSpec = Field(default_factory=IntrinsicsSpec)
        noise: NoiseSpec = Field(default_factory=NoiseSpec)
        min_range_m: float = Field(0.2, gt=0.0)
        max_range_m: float = Field(2.0, gt=0.0)
        mount: MountSpec = Field(default_factory=MountSpec)
        parts: tuple[PartSpec, ...] = Field(default=(), description="workpieces in the scene")
        board: BoardSpecParams | None = Field(None, description="a calibration board fixed in the cell")
        image: ImageSpec = Field(default_factory=ImageSpec, description="the board's intensity image")
        effects: dict[str, Any] = Field(default_factory=dict, description="sensor effects (camera/placement)")
        publish_cloud: bool = Field(True, description="also publish each capture on the cloud port")
        publish_depth: bool = Field(True, description="publish the depth image of each capture")
        decimate: int = Field(1, ge=1, le=16, description="keep every n-th valid point (smaller clouds)")
        cloud_decimate: int = Field(
            1, ge=1, le=64, description="the cloud port shows every n-th point of each capture (the reply keeps all)"
        )
        frame_id: str = Field("camera", min_length=1, description="the camera's frame on its messages and frames")

        @model_validator(mode="after")
        def _part_frames(self) -> SimCamera.Params:
            taken = {*CELL_FRAMES, self.frame_id}
            named = [(f"parts[{i}]", part.name) for i, part in enumerate(self.parts)]
            if self.board is not None:
                named.append(("board", self.board.name))
            for where, name in named:
                if name in taken or name.startswith(TRUTH_PREFIX):
                    raise ValueError(
                        f"{where}: the name {name!r} is a frame the cell already has (or a truth frame); "
                        f"a part's name is its frame: choose another (taken: {', '.join(sorted(taken))})"
                    )
                taken.add(name)
            return self

    def setup(self) -> None:
        p: SimCamera.Params = self.params  # type: ignore[assignment]
        intr = self._intrinsics(p.intrinsics)
        if p.noise.preset in NOISE_PRESETS:
            noise = getattr(DepthNoiseModel, p.noise.preset)()
        else:
            noise = DepthNoiseModel(
                p.noise.sigma_const_m, p.noise.sigma_quad_per_m, p.noise.grazing_dropout_deg, p.noise.dropout_prob
            )
        noise = replace(noise, depth_unit_m=p.noise.depth_unit_m)
        model = DepthCameraModel(intr, noise, p.min_range_m, p.max_range_m)
        parts = [PartPlacement(ps.name, make_workpiece(ps.workpiece), ps.pose.T(), ps.parent) for ps in p.parts]
        self.imager: BoardImager | None = None
        if p.board is not None:
            board = parse_board(p.board.spec)
            parts.append(PartPlacement(p.board.name, board_workpiece(board, p.board.name), p.board.pose.T(), "world"))
            opts = {"noise_sigma": p.image.noise_sigma, "blur_sigma_px": p.image.blur_sigma_px}
            self.imager = BoardImager.for_depth_camera(
                board, intr, p.image.distortion, supersample=p.image.supersample, **opts
            )
        mount = CameraMount(p.mount.kind, p.mount.pose.T())
        self.cell = SimCell(model, mount, parts, SensorEffects.from_dict(p.effects))
        self.intrinsics = intr
        self.ctx.publish(
            "scene",
            SceneMeshes(
                meshes=[Mesh(pp.name, pp.name, pp.workpiece.vertices(), pp.workpiece.triangles()) for pp in parts]
            ),
        )

    @staticmethod
    def _intrinsics(s: IntrinsicsSpec) -> CameraModel:
        d = default_intrinsics()
        sx, sy = s.width / d.width, s.height / d.height
        fx = s.fx or d.fx * sx
        fy = s.fy or d.fy * sy
        return CameraModel.pinhole(
            s.width,
            s.height,
            fx,
            fy,
            s.cx if s.cx is not None else (s.width - 1) / 2.0,
            s.cy if s.cy is not None else (s.height - 1) / 2.0,
        )

    def _tcp_truth(self) -> np.ndarray | None:
        if not self.cell._needs_tcp():
            return None
        reply = self.ctx.call("robot", Request(command="truth"))
        if not reply.ok or reply.T is None:
            raise RuntimeError(f"the simulated robot did not give its TCP pose: {reply.error}")
        return reply.T

    def _place(self, request: Request) -> Request:
        """Move a part lying in the world (a simulated controller's next part, at a new offset)."""
        from engine.run.cell.protocol import pose_from_doc

        name = request.args.get("part")
        index = next((i for i, pp in enumerate(self.cell.parts) if pp.name == name), None)
        if index is None or self.cell.parts[index].parent != "world":
            lying = [pp.name for pp in self.cell.parts if pp.parent == "world"]
            raise ValueError(f"no part {name!r} lying in the world (parts: {', '.join(lying)})")
        T = pose_from_doc(request.args.get("pose"), "pose")
        self.cell.parts[index] = replace(self.cell.parts[index], T_parent_part=T)
        return Request(command="placed", args={"part": name})

    def _fault(self, request: Request) -> Request:
        """A camera fault from now on: ``disconnect`` (the next ``captures`` captures fail, as a cable
        pulled and put back does) or ``hang`` (the next capture takes ``seconds`` of wall time, as a
        stalled USB link does); the cell service must answer camera_fault and go on."""
        kind, args = request.args.get("kind"), request.args
        if kind == "disconnect":
            self._fail_captures = int(args.get("captures", 1))
        elif kind == "hang":
            self._hang_s = float(args.get("seconds", 1.0))
        else:
            raise ValueError(f"fault kind {kind!r}: disconnect or hang")
        return Request(command="fault", args={"kind": kind})

    def on_request(self, service: str, request: Any) -> Any:
        if service == "place":
            return self._place(request)
        if service == "fault":
            return self._fault(request)
        if getattr(self, "_fail_captures", 0) > 0:
            self._fail_captures -= 1
            raise ConnectionError("camera disconnected (simulated fault): no frame")
        if getattr(self, "_hang_s", 0.0) > 0:
            hang, self._hang_s = self._hang_s, 0.0
            time.sleep(hang)  # (wall time: a device that stalls, whatever the run's clock)
        p: SimCamera.Params = self.params  # type: ignore[assignment]
        T_world_tcp = self._tcp_truth()
        t = self.ctx.clock.now_s()
        cap, truth = self.cell.capture(T_world_tcp, self.ctx.rng, t)
        stamp = round(t * 1e9)  # the sensor's own time stamp of the frame
        cloud = PointCloud(points=cap.points[:: p.decimate].astype(np.float32), frame_id=p.frame_id, stamp_ns=stamp)
        if p.publish_depth:
            self.ctx.publish("depth", Image(data=cap.depth, encoding="32FC1", frame_id=p.frame_id, stamp_ns=stamp))
            intr = self.intrinsics
            info = CameraInfo(width=intr.width, height=intr.height, K=intr.K, frame_id=p.frame_id, stamp_ns=stamp)
            self.ctx.publish("camera_info", info)
        if self.imager is not None and p.board is not None:
            gray = self.imager.render(truth.T_cam_parts[p.board.name], self.ctx.rng)
            self.ctx.publish("image_info", self.imager.camera.to_camera_info(p.frame_id, stamp))
            self.ctx.publish("image", Image(data=gray, encoding="mono8", frame_id=p.frame_id, stamp_ns=stamp))
        if p.publish_cloud:
            self.ctx.publish("cloud", thinned(cloud, p.cloud_decimate))
        own = {"camera": p.frame_id}  # SimCell names its camera "camera"
        frames = [
            Transform(frame_id=f.parent, child_frame_id=own.get(f.child, f.child), T=f.T_parent_child, stamp_ns=stamp)
            for f in self.cell.frames(T_world_tcp, t)
            if f.child not in ("base", "tcp")  # the robot publishes those
        ]
        self.ctx.publish("frames", FrameTransforms(stamp_ns=stamp, transforms=frames))
        true_poses = {**truth.T_world_parts, p.frame_id: truth.T_world_cam}
        if truth.T_world_tcp is not None:
            true_poses["tcp"] = truth.T_world_tcp
        truth_tf = [
            Transform(frame_id="world", child_frame_id=truth_frame(name), T=T, stamp_ns=stamp)
            for name, T in true_poses.items()
        ]
        self.ctx.publish("truth/part_poses", FrameTransforms(stamp_ns=stamp, transforms=truth_tf))
        return cloud
