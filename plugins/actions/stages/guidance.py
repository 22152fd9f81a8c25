"""``guidance``: the iterative guidance loop of seed 000 as one action stage.

Per trigger: (optionally) move to the photo pose, record ``T_start``; then look (capture + match),
and while the match is not within tolerance, compute the correction step (plugins.actions.
guidance_math), check it against the limits, move, and look again — at most ``max_iterations``
moves. The result (``T_start``, ``T_end``, residual per look, verdict) goes out on ``result`` for
the docking stage, then a ``done`` request that can trigger a second guidance stage (dual docking:
the eye-in-hand look at the target first, then the eye-to-hand look at the gripped part). A stage
triggered by a ``done`` whose verdict is not ``converged`` moves nothing: it publishes a refused
result (alarm ``upstream_not_converged``), so the pairing downstream still holds.

Safety (docs/design.md): no motion from a failed or ambiguous match, a NaN anywhere, a step or a total
correction beyond the limits, or a refused/unanswered robot; each ends the run with an ``alarm``
event and a result whose verdict is not ``converged``, so nothing docks. Not converging within
``max_iterations`` raises an alarm too. Robot command ids are ``<stage>-<job>-<k>``: a replayed or
repeated trigger never moves twice (the robot answers ``duplicate`` and guidance stops with an alarm).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import PointCloud, Request, RobotReply
from engine.stage import ServiceError, ServiceSpec, Stage, StageParams, input_file
from plugins.actions import guidance_math as gm
from plugins.actions import robot_moves
from plugins.actions.hand_eye_source import load_hand_eye
from plugins.actions.messages import GuidanceResult
from plugins.interfaces import CAMERA_CAPTURE, ROBOT_MOVE
from plugins.params import PoseSpec
from plugins.registration.messages import MatchResult

MATCH = ServiceSpec(PointCloud, MatchResult)
MATCH_FIRST = ServiceSpec(PointCloud, MatchResult, "matcher.match_first (default: the match client)", optional=True)


class GuidanceStopError(Exception):
    """Ends a guidance run without docking: verdict, alarm code and message."""

    def __init__(self, verdict: str, code: str, message: str) -> None:
        super().__init__(message)
        self.verdict, self.code = verdict, code


class Guidance(Stage):
    """Iterative visual guidance (eye-in-hand or eye-to-hand) until the view matches the template."""

    type_name = "guidance"
    role = "action"
    inputs: ClassVar = {"trigger": Request}
    outputs: ClassVar = {"result": GuidanceResult, "done": Request}  # done: chains a second guidance (dual)
    uses: ClassVar = {
        "robot": ROBOT_MOVE,
        "state": ServiceSpec(Request, RobotReply, "robot.state (needed when there is no photo_pose)", optional=True),
        "camera": CAMERA_CAPTURE,
        "match": MATCH,
        "match_first": MATCH_FIRST,
    }

    class Params(StageParams):
        mode: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand"
        hand_eye: PoseSpec | None = Field(None, description="T_tcp_cam (eye in hand) or T_base_cam (eye to hand)")
        hand_eye_file: str | None = input_file(None, description="calibration result JSON (vgr calibrate ... --json)")
        photo_pose: PoseSpec | None = Field(None, description="T_base_tcp to start from; None: where the robot is")
        translation_tol_mm: float = Field(0.1, gt=0.0)
        rotation_tol_deg: float = Field(0.01, gt=0.0)
        max_iterations: int = Field(5, ge=1, le=50)
        max_step_mm: float = Field(30.0, gt=0.0, description="largest single correction move")
        max_step_deg: float = Field(15.0, gt=0.0)
        max_total_mm: float = Field(40.0, gt=0.0, description="largest distance from T_start")
        max_total_deg: float = Field(20.0, gt=0.0)
        motion: Literal["move_l", "move_j"] = "move_l"
        speed: float = Field(0.0, ge=0.0, description="0 = the robot's default")
        timeout_s: float = Field(30.0, gt=0.0)

    def setup(self) -> None:
        p: Guidance.Params = self.params  # type: ignore[assignment]
        self.X = self._hand_eye(p)
        self.tol = (p.translation_tol_mm / 1e3, float(np.radians(p.rotation_tol_deg)))

    def _hand_eye(self, p: Guidance.Params) -> np.ndarray:
        return load_hand_eye(self.ctx, p.mode, p.hand_eye, p.hand_eye_file)

    # -- services ------------------------------------------------------------------------------
    def _move(self, job: int, k: str, T: np.ndarray, kind: str) -> RobotReply:
        p: Guidance.Params = self.params  # type: ignore[assignment]
        try:
            return robot_moves.move(
                self.ctx, f"{self.ctx.name}-{job}-{k}", T, kind, speed=p.speed, timeout_s=p.timeout_s
            )
        except robot_moves.MoveRefused as exc:
            verdict = "failed" if exc.code == "robot_unavailable" else "refused"
            raise GuidanceStopError(verdict, exc.code, str(exc)) from None

    def _where_is_the_robot(self) -> np.ndarray:
        p: Guidance.Params = self.params  # type: ignore[assignment]
        if not self.ctx.has_client("state"):
            raise GuidanceStopError("failed", "no_photo_pose", "no photo_pose and no `state` client wired to the robot")
        try:
            reply = self.ctx.call("state", Request(command="state"), timeout_s=p.timeout_s)
        except ServiceError as exc:
            raise GuidanceStopError("failed", "robot_unavailable", str(exc)) from None
        if not reply.ok or reply.T is None:
            raise GuidanceStopError("failed", "robot_state", f"the robot did not report its pose: {reply.error}")
        return reply.T

    def _look(self, first: bool) -> MatchResult:
        p: Guidance.Params = self.params  # type: ignore[assignment]
        try:
            cloud = self.ctx.call("camera", Request(command="capture"), timeout_s=p.timeout_s)
        except ServiceError as exc:
            raise GuidanceStopError("failed", "capture_failed", str(exc)) from None
        client = "match_first" if first and self.ctx.has_client("match_first") else "match"
        try:
            return self.ctx.call(client, cloud, timeout_s=p.timeout_s)
        except ServiceError as exc:
            raise GuidanceStopError("failed", "matcher_failed", str(exc)) from None

    # -- the loop ------------------------------------------------------------------------------
    def on_message(self, port: str, msg: Request) -> None:  # type: ignore[override]
        p: Guidance.Params = self.params  # type: ignore[assignment]
        job = msg.seq
        result = GuidanceResult(
            mode=p.mode,
            job=job,
            frame_id="base",
            translation_tol_mm=p.translation_tol_mm,
            rotation_tol_deg=p.rotation_tol_deg,
        )
        try:
            upstream = msg.args.get("verdict") if isinstance(msg.args, dict) else None
            if upstream is not None and upstream != "converged":  # chained after another guidance (dual)
                why = f"the guidance that triggered this one ended {upstream!r} (its job {msg.args.get('job')})"
                raise GuidanceStopError("refused", "upstream_not_converged", f"{why}: nothing moved")
            self._run(job, result)
        except GuidanceStopError as stop:
            result.verdict = stop.verdict if result.verdict != "converged" else result.verdict
            result.reasons.append(str(stop))
            self.ctx.event("alarm", stop.code, str(stop), job=job, moves=result.moves)
        self.ctx.publish("result", result)
        self.ctx.publish("done", Request(command="guidance_done", args={"job": job, "verdict": result.verdict}))

    def _run(self, job: int, result: GuidanceResult) -> None:
        p: Guidance.Params = self.params  # type: ignore[assignment]
        if p.photo_pose is not None:
            T_cur = self._move(job, "photo", p.photo_pose.T(), "move_j").T
        else:
            T_cur = self._where_is_the_robot()
        result.T_start = result.T_end = T_cur
        for look in range(p.max_iterations + 1):
            match = self._look(first=look == 0)
            result.match_verdicts.append(match.verdict)
            if not match.usable:
                reasons = "; ".join(match.reasons) or "no reason given"
                raise GuidanceStopError(
                    "failed", f"match_{match.verdict}", f"look {look}: match {match.verdict}: {reasons}"
                )
            T_match = np.asarray(match.T_match, dtype=float)
            if not np.all(np.isfinite(T_match)):
                raise GuidanceStopError("failed", "nan", f"look {look}: T_match contains NaN")
            result.matches.append(T_match)
            t, r = gm.size_of(T_match)
            result.residual_mm.append(t * 1e3)
            result.residual_deg.append(float(np.degrees(r)))
            self.ctx.event(
                "info",
                "guidance_look",
                f"look {look}: residual {t * 1e3:.4f} mm / {np.degrees(r):.4f} deg",
                job=job,
                look=look,
                residual_mm=t * 1e3,
                residual_deg=float(np.degrees(r)),
            )
            if gm.converged(T_match, *self.tol):
                result.verdict = "converged"
                return
            if look == p.max_iterations:
                raise GuidanceStopError(
                    "not_converged",
                    "not_converged",
                    f"not converged after {p.max_iterations} moves: residual {t * 1e3:.3f} mm / "
                    f"{np.degrees(r):.4f} deg ({gm.not_converged_hint(result.residual_mm, result.residual_deg, p)})",
                )
            if p.mode == "eye_in_hand":
                T_next = T_cur @ gm.delta_eye_in_hand(T_match, self.X)
            else:
                T_next = gm.delta_eye_to_hand(T_match, self.X) @ T_cur
            self._check_limits(T_cur, T_next, result.T_start)
            T_cur = self._move(job, str(look + 1), T_next, p.motion).T
            result.moves += 1
            result.T_end = T_cur

    def _check_limits(self, T_cur: np.ndarray, T_next: np.ndarray, T_start: np.ndarray) -> None:
        p: Guidance.Params = self.params  # type: ignore[assignment]
        if not np.all(np.isfinite(T_next)):
            raise GuidanceStopError("refused", "nan", "the correction contains NaN")
        problem = gm.over_limit(T_cur, T_next, p.max_step_mm, p.max_step_deg, "step") or gm.over_limit(
            T_start, T_next, p.max_total_mm, p.max_total_deg, "total correction"
        )
        if problem:
            raise GuidanceStopError("refused", "correction_limit", problem)
