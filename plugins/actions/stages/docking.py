"""``docking`` and ``dual_docking``: apply the guidance correction to the taught install pose and move.

Formulas (plugins.actions.guidance_math, seed 000):

* eye-in-hand (the incoming part moved):    ``T_end T_start^-1 T_install``  (left, base frame)
* eye-to-hand (the grasp changed):          ``T_install T_start^-1 T_end``  (right, tool frame)
* dual (both; stage 1 eye-in-hand sees the target, stage 2 eye-to-hand sees the gripped part):
  ``T_end1 T_start1^-1 T_install T_start2^-1 T_end2``

Refused, with an ``alarm`` and a ``Correction`` whose verdict is ``refused`` and no motion: a
guidance result that did not converge (or of the wrong mode), NaN, or a correction larger than the
limits. With ``approach_mm`` > 0 the robot first goes to the corrected pose backed off along the
tool's -z axis, then moves linearly in. ``execute: false`` computes and publishes without moving.
Command ids ``<stage>-<job>[-approach]`` never execute twice.
"""

from __future__ import annotations

from collections import deque
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import Correction
from engine.stage import Stage, StageParams
from engine.transforms import T_from_Rt
from plugins.actions import guidance_math as gm
from plugins.actions import robot_moves
from plugins.actions.messages import GuidanceResult
from plugins.interfaces import ROBOT_MOVE
from plugins.params import PoseSpec


class _DockingBase(Stage):
    role = "action"
    outputs: ClassVar = {"correction": Correction}
    uses: ClassVar = {"robot": ROBOT_MOVE}

    class Params(StageParams):
        install_pose: PoseSpec = Field(description="taught T_base_tcp of the install (dock) pose")
        max_correction_mm: float = Field(25.0, gt=0.0, description="largest allowed |install correction|")
        max_correction_deg: float = Field(12.0, gt=0.0)
        approach_mm: float = Field(0.0, ge=0.0, description="back-off along tool -z before the final linear move")
        motion: Literal["move_l", "move_j"] = "move_j"
        speed: float = Field(0.0, ge=0.0)
        execute: bool = Field(True, description="false: compute and publish the correction, do not move")
        timeout_s: float = Field(30.0, gt=0.0)

    def _refuse(self, job: int, code: str, reason: str) -> None:
        self.ctx.event("alarm", code, reason, job=job)
        self.ctx.publish(
            "correction", Correction(kind="install_corrected", frame_id="base", verdict="refused", reasons=[reason])
        )

    def _dock(self, job: int, T_corrected: np.ndarray) -> None:
        p: _DockingBase.Params = self.params  # type: ignore[assignment]
        T_install = p.install_pose.T()
        if not np.all(np.isfinite(T_corrected)):
            self._refuse(job, "nan", "the corrected install pose contains NaN")
            return
        t, r = gm.correction_between(T_install, T_corrected)
        problem = gm.over_limit(T_install, T_corrected, p.max_correction_mm, p.max_correction_deg, "install correction")
        if problem:
            self._refuse(job, "correction_limit", problem)
            return
        if p.execute:
            try:
                if p.approach_mm > 0:
                    back = T_from_Rt(np.eye(3), (0.0, 0.0, -p.approach_mm / 1e3))
                    self._move(job, "approach", T_corrected @ back, "move_j")
                    self._move(job, "dock", T_corrected, "move_l")
                else:
                    self._move(job, "dock", T_corrected, p.motion)
            except robot_moves.MoveRefused as exc:
                self._refuse(job, exc.code, str(exc))
                return
        self.ctx.event(
            "info",
            "docked" if p.execute else "correction_computed",
            f"install correction {t * 1e3:.3f} mm / {np.degrees(r):.4f} deg",
            job=job,
            correction_mm=t * 1e3,
            correction_deg=float(np.degrees(r)),
        )
        self.ctx.publish(
            "correction", Correction(kind="install_corrected", frame_id="base", T=T_corrected, verdict="ok")
        )

    def _move(self, job: int, k: str, T: np.ndarray, kind: str) -> None:
        p: _DockingBase.Params = self.params  # type: ignore[assignment]
        robot_moves.move(self.ctx, f"{self.ctx.name}-{job}-{k}", T, kind, speed=p.speed, timeout_s=p.timeout_s)

    def _usable(self, g: GuidanceResult, mode: str) -> str | None:
        if g.mode != mode:
            return f"a {g.mode} guidance result reached a {mode} input"
        if not g.converged:
            return f"guidance job {g.job} did not converge ({g.verdict}: {'; '.join(g.reasons) or 'no reason'})"
        return None


class Docking(_DockingBase):
    """Corrects the taught install pose with one guidance result and moves there."""

    type_name = "docking"
    inputs: ClassVar = {"guidance": GuidanceResult}

    class Params(_DockingBase.Params):
        mode: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand"

    def on_message(self, port: str, msg: GuidanceResult) -> None:  # type: ignore[override]
        p: Docking.Params = self.params  # type: ignore[assignment]
        problem = self._usable(msg, p.mode)
        if problem:
            self._refuse(msg.job, "guidance_not_usable", problem)
            return
        T_install = p.install_pose.T()
        formula = gm.dock_eye_in_hand if p.mode == "eye_in_hand" else gm.dock_eye_to_hand
        try:
            T_corrected = formula(msg.T_start, msg.T_end, T_install)
        except ValueError as exc:  # NaN or a non-rigid pose in the guidance result
            self._refuse(msg.job, "nan" if "NaN" in str(exc) else "invalid_pose", f"cannot correct: {exc}")
            return
        self._dock(msg.job, T_corrected)


class DualDocking(_DockingBase):
    """Corrects the install pose with an eye-in-hand (target) and an eye-to-hand (grasp) result."""

    type_name = "dual_docking"
    inputs: ClassVar = {"in_hand": GuidanceResult, "to_hand": GuidanceResult}

    def setup(self) -> None:
        self.pending: dict[str, deque[GuidanceResult]] = {"in_hand": deque(), "to_hand": deque()}

    def on_message(self, port: str, msg: GuidanceResult) -> None:  # type: ignore[override]
        self.pending[port].append(msg)
        while self.pending["in_hand"] and self.pending["to_hand"]:
            g1, g2 = self.pending["in_hand"].popleft(), self.pending["to_hand"].popleft()
            problem = self._usable(g1, "eye_in_hand") or self._usable(g2, "eye_to_hand")
            if problem:
                self._refuse(g2.job, "guidance_not_usable", problem)
                continue
            p: DualDocking.Params = self.params  # type: ignore[assignment]
            try:
                T_corrected = gm.dock_dual(g1.T_start, g1.T_end, p.install_pose.T(), g2.T_start, g2.T_end)
            except ValueError as exc:  # NaN or a non-rigid pose in a guidance result
                self._refuse(g2.job, "nan" if "NaN" in str(exc) else "invalid_pose", f"cannot correct: {exc}")
                continue
            self._dock(g2.job, T_corrected)

    def finish(self) -> None:
        left = {k: len(v) for k, v in self.pending.items() if v}
        if left:
            self.ctx.event("alarm", "unpaired_guidance", f"guidance results without a partner: {left}", **left)
