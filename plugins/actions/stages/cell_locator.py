"""``cell_locator``: the jobs of a cell service when the robot program is the master (``vgr serve``).

The controller moves the robot itself; it sends the robot's current flange pose with each request
and gets an answer back (engine.run.cell.protocol; docs/cell_service.md). Two services, both taking a
:class:`~engine.messages.Request` (``args`` = the API request document) and replying a
:class:`~engine.messages.CellReply` with a status of engine.run.cell.codes:

The robot's pose comes as ``pose`` (the flange ``T_base_tcp``), or as ``joints_rad`` when the recipe
names the ``robot_model`` (the pose is then its forward kinematics), or, in simulation
(``pose_from_robot``), from the robot stage.

``locate``  capture, match (``match_first``: global registration, the part may be anywhere), and the
    correction the controller applies to its taught poses. Eye-in-hand (the part moved by ``D``,
    base frame, left-multiply): with ``C = T_base_tcp T_tcp_cam`` now and ``C0`` at the template's
    photo pose, ``T_match = C0^-1 P0 P^-1 C`` (plugins.actions.guidance_math) gives
    ``D = P P0^-1 = C T_match^-1 C0^-1``. Eye-to-hand (the grasp changed, tool frame,
    right-multiply): ``R = G0 G^-1 = T0^-1 C T_match C^-1 T`` with ``C = T_base_cam``. The reply
    carries the correction, each of the recipe's ``targets`` corrected, the match quality and its
    uncertainty. ``count`` > 1 finds up to that many parts in one capture: after each part the
    capture's points within ``part_radius_mm`` of the part's template points are removed and the rest
    matched again. ``parts`` holds the parts within the limits (the reply is ``ok`` when there is at
    least one), ``rejected`` those beyond them, with the reason: listed for the record, never to use.
``guide``   one step of the iterative guidance loop (seed 000) with the robot as master: ``step`` 0 is
    the first look (global), later steps look with ``match`` (fine, from identity). The reply is the
    next flange pose to move to, or ``converged`` with the correction (``T_end T_start^-1``, the
    docking formula of plugins.actions.guidance_math), or a refusal. The request carries
    ``start_pose`` (the pose of step 0), so the service keeps no state between requests: any
    request replays on its own, and a service restart mid-guidance loses nothing.

Safety, as in the guidance stage: no correction from a failed or ambiguous match, a NaN anywhere, a
correction or a step beyond the limits (status ``out_of_limits``); each refusal is an ``alarm``
event. The robot pose a request sends is checked (finite, rigid) before anything is captured.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from engine.messages import CellReply, PointCloud, Request, RobotReply
from engine.run.cell.protocol import InvalidRequest, pose_doc, pose_from_doc
from engine.stage import ServiceError, ServiceSpec, Stage, StageParams, input_file
from engine.transforms import inv, transform_points
from plugins.actions import guidance_math as gm
from plugins.actions.hand_eye_source import load_hand_eye
from plugins.interfaces import CAMERA_CAPTURE
from plugins.params import PoseSpec
from plugins.registration.messages import MatchResult
from plugins.registration.template import load_template
from plugins.robot.model_file import load_robot_model

JOB = ServiceSpec(Request, CellReply, "one cell-service job (engine.run.cell)")
MATCH = ServiceSpec(PointCloud, MatchResult)
MIN_POINTS_LEFT = 50  # fewer points than this after removing the parts found: no further part is looked for


class Refusal(Exception):  # noqa: N818 - an answer, not a program error
    """Ends a job with a status other than ok (and an alarm naming *code*)."""

    def __init__(self, status: str, message: str, result: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.status, self.result = status, result or {}


class CellLocator(Stage):
    """Locate parts and guide a robot that is its own master (the cell service's locate and guide)."""

    type_name = "cell_locator"
    role = "action"
    services: ClassVar = {"locate": JOB, "guide": JOB}
    uses: ClassVar = {
        "camera": CAMERA_CAPTURE,
        "match_first": ServiceSpec(PointCloud, MatchResult, "matcher.match_first: a part anywhere"),
        "match": ServiceSpec(PointCloud, MatchResult, "matcher.match: later guide steps", optional=True),
        "state": ServiceSpec(Request, RobotReply, "robot.state (pose_from_robot: simulation)", optional=True),
    }

    class Params(StageParams):
        mode: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand"
        hand_eye: PoseSpec | None = Field(None, description="T_tcp_cam (eye in hand) or T_base_cam (eye to hand)")
        hand_eye_file: str | None = input_file(None, description="calibration result JSON (vgr calibrate ... --json)")
        template: str = input_file(description="the matcher's template (.vgrtpl): its photo pose and points")
        photo_pose: PoseSpec | None = Field(None, description="T_base_tcp of the template (default: its own)")
        targets: dict[str, PoseSpec] = Field(default_factory=dict, description="taught poses corrected in each reply")
        max_correction_mm: float = Field(50.0, gt=0.0, description="largest move of any target (or the photo pose)")
        max_correction_deg: float = Field(15.0, gt=0.0)
        max_parts: int = Field(8, ge=1, le=64, description="largest count a locate may ask for")
        part_radius_mm: float = Field(3.0, gt=0.0, description="points this close to a found part are its own")
        translation_tol_mm: float = Field(0.05, gt=0.0, description="guide: converged within this")
        rotation_tol_deg: float = Field(0.02, gt=0.0)
        max_iterations: int = Field(5, ge=1, le=50, description="guide: moves before not_converged")
        max_step_mm: float = Field(30.0, gt=0.0)
        max_step_deg: float = Field(15.0, gt=0.0)
        max_total_mm: float = Field(40.0, gt=0.0, description="guide: largest distance from the start pose")
        max_total_deg: float = Field(20.0, gt=0.0)
        pose_from_robot: bool = Field(False, description="a request without pose takes the `state` client's")
        robot_model: str | None = Field(
            None, description="robot model (name or file): a request may send joints_rad instead of its pose"
        )
        T_flange_tcp: PoseSpec | None = Field(None, description="the tool on the flange (default: the model's)")
        timeout_s: float = Field(10.0, gt=0.0)

    def setup(self) -> None:
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        self.X = load_hand_eye(self.ctx, p.mode, p.hand_eye, p.hand_eye_file)
        template = load_template(self.ctx.input_path(p.template))
        self.T_photo = p.photo_pose.T() if p.photo_pose is not None else np.asarray(template.T_base_tcp_photo)
        self.template_points = template.points
        self.targets = {name: pose.T() for name, pose in p.targets.items()}
        self.model = None if p.robot_model is None else load_robot_model(p.robot_model)
        if self.model is not None and p.T_flange_tcp is not None:
            self.model = self.model.with_tool(p.T_flange_tcp.T())
        if p.pose_from_robot and not self.ctx.has_client("state"):
            raise ValueError("pose_from_robot needs the `state` client wired to the robot")

    # -- the service ---------------------------------------------------------------------------
    def on_request(self, service: str, request: Request) -> CellReply:  # type: ignore[override]
        args = request.args if isinstance(request.args, dict) else {}
        try:
            if service == "locate":
                message, result = self._locate(args)
            else:
                message, result = self._guide(args)
        except Refusal as refused:
            self.ctx.event("alarm", refused.status, str(refused), service=service, id=args.get("id"))
            return CellReply(status=refused.status, message=str(refused), result=refused.result)
        except InvalidRequest as exc:
            return CellReply(status="invalid_request", message=str(exc))
        return CellReply(status="ok", message=message, result=result)

    # -- locate --------------------------------------------------------------------------------
    def _locate(self, args: dict[str, Any]) -> tuple[str, dict[str, Any]]:
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        count = _integer(args.get("count", 1), "count", 1, p.max_parts)
        T = self._robot_pose(args, "pose")
        cloud = self._capture()
        parts: list[dict[str, Any]] = []  # within the limits: the controller may use them
        rejected: list[dict[str, Any]] = []  # found, but beyond the limits: listed, never to be used
        for k in range(count):
            match = self._match("match_first", cloud)
            if not match.usable:
                if k == 0:
                    status = "ambiguous" if match.verdict == "ambiguous" else "no_part"
                    raise Refusal(status, f"match {match.verdict}: {'; '.join(match.reasons) or 'no reason given'}")
                break
            part, problem = self._part(T, match)
            if problem:
                rejected.append({**part, "refused": problem})
            else:
                parts.append(part)
            if k + 1 < count:
                cloud = self._without_part(cloud, match)
                if cloud.points.shape[0] < MIN_POINTS_LEFT:
                    break
        result = {
            "frame": self._frame(),
            "requested": count,
            "found": len(parts),
            "pose": pose_doc(T),
            "parts": parts,
            "rejected": rejected,
        }
        if not parts:  # (one part asked for, or none of several within the limits: nothing to use)
            raise Refusal("out_of_limits", "; ".join(r["refused"] for r in rejected), result)
        found = f"{len(parts)} of {count} parts" if count > 1 else "the part"
        beyond = f"; {len(rejected)} more beyond the limits" if rejected else ""
        first = parts[0]
        return (
            f"located {found}: correction {first['translation_mm']:.3f} mm / {first['rotation_deg']:.3f} deg{beyond}",
            result,
        )

    def _frame(self) -> str:
        """Where the correction applies: ``base`` (left-multiply) or ``tool`` (right-multiply)."""
        return "base" if self.params.mode == "eye_in_hand" else "tool"  # type: ignore[attr-defined]

    def _correction(self, T: np.ndarray, T_match: np.ndarray) -> np.ndarray:
        if self.params.mode == "eye_in_hand":  # type: ignore[attr-defined]
            return T @ self.X @ inv(T_match) @ inv(self.T_photo @ self.X)
        C = self.X
        return inv(self.T_photo) @ C @ T_match @ inv(C) @ T

    def _apply(self, D: np.ndarray, T_taught: np.ndarray) -> np.ndarray:
        return D @ T_taught if self._frame() == "base" else T_taught @ D

    def _part(self, T: np.ndarray, match: MatchResult) -> tuple[dict[str, Any], str | None]:
        """One found part's reply entry, and why its correction breaks the limits (None: within)."""
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        D = self._correction(T, np.asarray(match.T_match, dtype=float))
        if not np.all(np.isfinite(D)):
            return {"correction": None}, "the correction is not finite"
        corrected = {name: self._apply(D, Tt) for name, Tt in self.targets.items()}
        checked = self.targets or {"photo_pose": self.T_photo}
        problem = next(
            (
                why
                for name, Tt in checked.items()
                if (why := gm.over_limit(Tt, self._apply(D, Tt), p.max_correction_mm, p.max_correction_deg, name))
            ),
            None,
        )
        t, r = gm.size_of(D)
        sigma = None if match.sigma is None else np.asarray(match.sigma, dtype=float)
        return {
            "correction": pose_doc(D),
            "translation_mm": t * 1e3,
            "rotation_deg": float(np.degrees(r)),
            "targets": {name: pose_doc(Tc) for name, Tc in corrected.items()},
            "fitness": float(match.fitness),
            "rmse_mm": float(match.inlier_rmse_m) * 1e3,
            "sigma_mm": None if sigma is None else [float(v) * 1e3 for v in sigma[:3]],
            "sigma_deg": None if sigma is None else [float(np.degrees(v)) for v in sigma[3:]],
        }, problem

    def _without_part(self, cloud: PointCloud, match: MatchResult) -> PointCloud:
        """*cloud* without the points of the part *match* found (those near its template points)."""
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        if self.template_points is None:
            return PointCloud(points=np.zeros((0, 3)), frame_id=cloud.frame_id)
        part = transform_points(inv(np.asarray(match.T_match, dtype=float)), self.template_points)
        near = cKDTree(part).query(cloud.points, k=1, distance_upper_bound=p.part_radius_mm / 1e3)[0]
        keep = ~np.isfinite(near)
        return PointCloud(points=np.ascontiguousarray(cloud.points[keep]), frame_id=cloud.frame_id)

    # -- guide ---------------------------------------------------------------------------------
    def _guide(self, args: dict[str, Any]) -> tuple[str, dict[str, Any]]:
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        step = _integer(args.get("step"), "step", 0, p.max_iterations)
        T = self._robot_pose(args, "pose")
        if "start_pose" in args:
            T_start = self._checked_pose(args["start_pose"], "start_pose")
        elif step == 0:
            T_start = T
        else:
            raise InvalidRequest("guide step > 0 needs start_pose: the pose of step 0")
        client = "match_first" if step == 0 or not self.ctx.has_client("match") else "match"
        match = self._match(client, self._capture())
        if not match.usable:
            status = "ambiguous" if match.verdict == "ambiguous" else "no_part"
            raise Refusal(status, f"step {step}: match {match.verdict}: {'; '.join(match.reasons) or 'no reason'}")
        T_match = np.asarray(match.T_match, dtype=float)
        t, r = gm.size_of(T_match)
        result: dict[str, Any] = {"frame": self._frame(), "step": step, "residual_mm": t * 1e3}
        result["residual_deg"] = float(np.degrees(r))
        if gm.converged(T_match, p.translation_tol_mm / 1e3, float(np.radians(p.rotation_tol_deg))):
            D = T @ inv(T_start) if self._frame() == "base" else inv(T_start) @ T
            result.update(converged=True, correction=pose_doc(D))
            result["targets"] = {name: pose_doc(self._apply(D, Tt)) for name, Tt in self.targets.items()}
            return f"converged at step {step}: residual {t * 1e3:.4f} mm / {np.degrees(r):.4f} deg", result
        if step == p.max_iterations:
            hint = gm.not_converged_hint([t * 1e3], [float(np.degrees(r))], p)
            raise Refusal("not_converged", f"not converged after {step} moves: {t * 1e3:.3f} mm left ({hint})", result)
        if p.mode == "eye_in_hand":
            T_next = T @ gm.delta_eye_in_hand(T_match, self.X)
        else:
            T_next = gm.delta_eye_to_hand(T_match, self.X) @ T
        problem = (
            ("the next pose is not finite" if not np.all(np.isfinite(T_next)) else None)
            or gm.over_limit(T, T_next, p.max_step_mm, p.max_step_deg, "step")
            or gm.over_limit(T_start, T_next, p.max_total_mm, p.max_total_deg, "total correction")
        )
        if problem:
            raise Refusal("out_of_limits", f"step {step}: {problem}", result)
        result.update(converged=False, next_pose=pose_doc(T_next))
        return f"step {step}: move on, residual {t * 1e3:.3f} mm / {np.degrees(r):.3f} deg", result

    # -- the robot's pose, the camera, the matcher ---------------------------------------------
    def _robot_pose(self, args: dict[str, Any], key: str) -> np.ndarray:
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        if key in args:
            return self._checked_pose(args[key], key)
        if "joints_rad" in args:
            return self._pose_of_joints(args["joints_rad"])
        if not p.pose_from_robot:
            raise Refusal("robot_pose_invalid", f"the request has no {key}: send the robot's flange pose")
        try:
            reply = self.ctx.call("state", Request(command="state"), timeout_s=p.timeout_s)
        except ServiceError as exc:
            raise Refusal("robot_pose_invalid", f"no pose sent and the robot did not report one: {exc}") from None
        if not reply.ok or reply.T is None:
            raise Refusal("robot_pose_invalid", f"no pose sent and the robot did not report one: {reply.error}")
        return np.asarray(reply.T, dtype=float)

    def _pose_of_joints(self, joints: Any) -> np.ndarray:
        """``T_base_tcp`` of the joint angles a request sent, by the recipe's robot model."""
        if self.model is None:
            raise Refusal("robot_pose_invalid", "joints_rad sent, but this cell has no robot_model: send the pose")
        try:
            q = np.asarray(joints, dtype=float)
            if q.shape != (self.model.dof,) or not np.all(np.isfinite(q)):
                raise ValueError(f"{self.model.dof} finite angles (rad) expected, got {joints!r}")
            return np.asarray(self.model.fk(q, frame="base"), dtype=float)
        except (TypeError, ValueError) as exc:
            raise Refusal("robot_pose_invalid", f"joints_rad: {exc}") from None

    @staticmethod
    def _checked_pose(doc: Any, name: str) -> np.ndarray:
        try:
            return pose_from_doc(doc, name)
        except InvalidRequest as exc:
            raise Refusal("robot_pose_invalid", str(exc)) from None

    def _capture(self) -> PointCloud:
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        try:
            cloud = self.ctx.call("camera", Request(command="capture"), timeout_s=p.timeout_s)
        except ServiceError as exc:
            raise Refusal("camera_fault", f"capture failed: {exc}") from None
        if cloud.points.shape[0] == 0:
            raise Refusal("camera_fault", "the capture holds no points (lens covered, exposure, range?)")
        return cloud

    def _match(self, client: str, cloud: PointCloud) -> MatchResult:
        p: CellLocator.Params = self.params  # type: ignore[assignment]
        try:
            return self.ctx.call(client, cloud, timeout_s=p.timeout_s)
        except ServiceError as exc:
            raise Refusal("fault", f"the matcher failed: {exc}") from None


def _integer(value: Any, name: str, low: int, high: int) -> int:
    """*value* as an integer in [low, high] (InvalidRequest naming *name* otherwise)."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InvalidRequest(f"{name} must be an integer from {low} to {high}, got {value!r}")
    return value
