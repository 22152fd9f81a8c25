"""``target_pose``: the pose of a known object in the camera, from registering a capture against its model.

The camera observation of hand-eye calibration in a 3D-camera cell: each capture of a known part
(e.g. ``feature_part``) is registered against the part's model with the registration library
(plugins.registration, docs/registration.md), giving ``T_cam_target`` (``target`` = the
part frame) for ``handeye_calibration``.

Model: the surface of the workpiece ``model`` (a simulated-cell workpiece name) or of the mesh file
``mesh_path`` (any format Open3D reads, metres, in the part frame), sampled with ``model_points``
points (seeded). A part resting on a table never shows its underside: points whose outward normal
has a part-frame z below ``visible_min_normal_z`` are left out (None keeps the whole surface), so
the underside cannot be matched to the top face.

Initial guess (``init: guess``, default): from the robot pose at the capture and the nominal
hand-eye and target poses (the CAD values; a few millimetres / a degree off is fine):
eye in hand ``T_cam_target0 = inv(T_base_tcp @ guess_hand_eye) @ guess_target`` (``guess_hand_eye``
= T_tcp_cam, ``guess_target`` = T_base_target); eye to hand ``inv(guess_hand_eye) @ T_base_tcp @
guess_target`` (T_base_cam, T_tcp_target). Then fine registration (``backend``, correspondences up to
``max_correspondence_m``). ``init: global`` ignores the guesses (global registration: slower, and on
model templates less reliable).

Inputs ``cloud`` (PointCloud, camera frame) and ``robot_pose`` (PoseStamped T_base_tcp), paired by
stamp (within ``max_skew_s``; ``calibration_poses`` gives both the capture's stamp). Output
``pose``: PoseStamped ``T_cam_target`` in the cloud's frame, stamped like the cloud, only for a
registration with verdict ok; failed or ambiguous ones raise a ``warning`` event and publish nothing
(the calibration then drops that robot pose).
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import PointCloud, PoseStamped
from engine.stage import Stage, StageParams, input_file
from engine.transforms import inv
from plugins.params import PoseSpec
from plugins.registration import FineParams, GlobalParams, prepare_cloud, register_fine, register_global
from plugins.util.mesh_surface import read_mesh, sample_surface


class TargetPose(Stage):
    """Pose of a known object in the camera (T_cam_target) by registering each capture against its model."""

    type_name = "target_pose"
    role = "solver"
    inputs: ClassVar = {"cloud": PointCloud, "robot_pose": PoseStamped}
    outputs: ClassVar = {"pose": PoseStamped}

    class Params(StageParams):
        model: str | None = Field("feature_part", description="simulated-cell workpiece name")
        mesh_path: str | None = input_file(None, description="or a mesh file (metres, part frame)")
        model_points: int = Field(100_000, ge=1000, le=5_000_000)
        visible_min_normal_z: float | None = Field(-0.3, ge=-1.0, le=1.0, description="None: whole surface")
        setup: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand"
        init: Literal["guess", "global"] = "guess"
        guess_hand_eye: PoseSpec = Field(default_factory=PoseSpec, description="nominal T_tcp_cam / T_base_cam")
        guess_target: PoseSpec = Field(default_factory=PoseSpec, description="nominal T_base_target / T_tcp_target")
        backend: str = Field("small_gicp_gicp", description="fine registration backend (docs/registration.md)")
        max_correspondence_m: float = Field(0.02, gt=0.0, description="fine ICP correspondence distance")
        max_skew_s: float = Field(0.05, ge=0.0, description="largest stamp difference cloud / robot pose")

    def setup(self) -> None:
        p: TargetPose.Params = self.params  # type: ignore[assignment]
        points, normals = self._model_surface(p)
        if p.visible_min_normal_z is not None:
            keep = normals[:, 2] >= p.visible_min_normal_z
            points = points[keep]
        self.fine = FineParams(backend=p.backend, max_correspondence_m=p.max_correspondence_m)
        self.global_params = GlobalParams(fine=self.fine, seed=self.ctx.seed)
        self.template = prepare_cloud(points, self.fine.preprocess)
        self.clouds: list[PointCloud] = []
        self.robot: list[PoseStamped] = []
        self.failed = 0

    def _model_surface(self, p: TargetPose.Params) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng([self.ctx.seed & 0xFFFFFFFF, 7])
        if p.mesh_path:
            mesh = read_mesh(self.ctx.input_path(p.mesh_path))
            return sample_surface(mesh.vertices, mesh.triangles, p.model_points, rng)
        if p.model:
            # a demo part by name (the parts the simulated cell shows)
            from plugins.util.workpieces import make_workpiece

            return make_workpiece(p.model).sample_points(p.model_points, rng)
        raise ValueError("target_pose needs `model` or `mesh_path`")

    def on_message(self, port: str, msg: Any) -> None:
        (self.clouds if port == "cloud" else self.robot).append(msg)
        self._match()

    def _match(self) -> None:
        p: TargetPose.Params = self.params  # type: ignore[assignment]
        while self.clouds and self.robot:
            cloud = self.clouds[0]
            stamps = np.array([r.stamp_ns for r in self.robot], dtype=np.int64)
            k = int(np.argmin(np.abs(stamps - cloud.stamp_ns)))
            if abs(int(stamps[k]) - cloud.stamp_ns) > p.max_skew_s * 1e9:
                if stamps.max() < cloud.stamp_ns:
                    return  # its robot pose has not arrived yet
                self.clouds.pop(0)
                self.ctx.event("warning", "no_robot_pose", f"capture at {cloud.stamp_ns / 1e9:.3f} s has no robot pose")
                continue
            self.clouds.pop(0)
            robot = self.robot.pop(k)
            self._register(cloud, np.asarray(robot.T, dtype=float))

    def _register(self, cloud: PointCloud, T_base_tcp: np.ndarray) -> None:
        p: TargetPose.Params = self.params  # type: ignore[assignment]
        points = np.asarray(cloud.points, dtype=float)
        if p.init == "global":
            res = register_global(points, self.template, self.global_params)
        else:
            X, Y = p.guess_hand_eye.T(), p.guess_target.T()
            T_cam_target0 = inv(T_base_tcp @ X) @ Y if p.setup == "eye_in_hand" else inv(X) @ T_base_tcp @ Y
            res = register_fine(points, self.template, inv(T_cam_target0), self.fine)
        if res.verdict != "ok" or res.T_match is None:
            self.failed += 1
            self.ctx.event(
                "warning",
                "registration_failed",
                f"capture at {cloud.stamp_ns / 1e9:.3f} s: registration {res.verdict}: {'; '.join(res.reasons[:2])}",
                verdict=res.verdict,
            )
            return
        T_cam_target = inv(res.T_match)  # T_match = T_target_cam maps camera points onto the model
        self.ctx.publish("pose", PoseStamped(T=T_cam_target, frame_id=cloud.frame_id, stamp_ns=cloud.stamp_ns))

    def finish(self) -> None:
        if self.clouds:
            self.ctx.event("warning", "no_robot_pose", f"{len(self.clouds)} capture(s) without a robot pose")
