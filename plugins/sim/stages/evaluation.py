"""``docking_evaluator``: how well a simulated cell docked, from ground truth (a sink: tests and benchmarks).

Reads the simulated robot's ``truth/tcp_pose`` (the true TCP after the last move), a simulated
camera's ``truth/part_poses`` (true part poses and the true TCP at the last capture, each under its
``truth/<frame>`` name; a bare name, as older recordings have it, reads the same) and the docking
stage's ``correction``, and at the end of the run reports the docking error in mm and degrees
(event ``docking_evaluation``; optionally a JSON file):

* ``eye_in_hand``: the TCP must sit on the target part as it did at teach time:
  error of ``TCP_final`` against ``P_true P_nominal^-1 T_install``;
* ``eye_to_hand``: the held part must reach the pose it had when the install pose was taught with the
  nominal grasp: ``TCP_final G_true`` against ``T_install G_nominal``;
* ``dual``: both: ``TCP_final G_true`` against ``F_true F_nominal^-1 T_install G_nominal``;
* ``assembly`` (seed 004): the held plate's pins against the base plate's holes: lateral offset of
  each pin axis from its hole axis at the pin root and tip; success when every offset is within the
  radial clearance (0.5 mm for 5 mm pins in 6 mm holes).

Robot effects are not inverted here: poses the recipe gives (install, nominal part, grasp) are taken
as true, which holds for a robot without injected kinematic errors (see docs/guidance.md).
"""

from __future__ import annotations

import json
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.files import create_new
from engine.messages import Correction, FrameTransforms, PoseStamped
from engine.stage import Stage, StageParams
from engine.transforms import inv, pose_error, transform_points
from plugins.params import PoseSpec
from plugins.sim.stages.camera import TRUTH_PREFIX
from plugins.util.workpieces import make_workpiece


class DockingEvaluator(Stage):
    """Docking error from simulation truth (never visible to solvers): mm, degrees, assembly success."""

    type_name = "docking_evaluator"
    role = "sink"
    inputs: ClassVar = {"correction": Correction, "robot_truth": PoseStamped, "part_truth": FrameTransforms}

    class Params(StageParams):
        scenario: Literal["eye_in_hand", "eye_to_hand", "dual", "assembly"]
        install_pose: PoseSpec | None = Field(None, description="taught install T_base_tcp")
        target_part: str | None = Field(None, description="part the install is relative to (eye_in_hand, dual)")
        target_nominal: PoseSpec | None = Field(None, description="its nominal world pose at teach time")
        held_part: str | None = Field(None, description="part in the gripper (eye_to_hand, dual, assembly)")
        grasp_nominal: PoseSpec | None = Field(None, description="nominal T_tcp_part of the held part")
        base_part: str | None = Field(None, description="assembly: the part with the holes")
        pins: tuple[str, ...] = ("pin1", "pin2")
        holes: tuple[str, ...] = ("hole1", "hole2")
        held_workpiece: str = "planar_plate"
        base_workpiece: str = "base_plate"
        clearance_mm: float = Field(0.5, gt=0.0)
        output: str | None = Field(None, description="also write the evaluation to this JSON file")

    def setup(self) -> None:
        self.last: dict[str, object] = {}

    def on_message(self, port: str, msg: object) -> None:
        self.last[port] = msg

    def finish(self) -> None:
        result = self.evaluate()
        p: DockingEvaluator.Params = self.params  # type: ignore[assignment]
        if p.output:  # (relative: inside the run folder; an absolute name must be a new file)
            with create_new(self.ctx.output_file(p.output)) as f:
                f.write(json.dumps(result, indent=2).encode())
        if result.get("error_mm") is None:
            text = f"not docked: {result['reason']}"
        elif p.scenario == "assembly":
            verdict = "assembled" if result["success"] else "NOT assembled"
            text = (
                f"{verdict}: worst pin offset {result['error_mm']:.4f} mm from its hole axis "
                f"(clearance {result['clearance_mm']} mm)"
            )
        else:
            text = f"docking error {result['error_mm']:.4f} mm / {result['error_deg']:.4f} deg"
        self.ctx.event("result", "docking_evaluation", f"truth: {text}", **result)

    def evaluate(self) -> dict[str, object]:
        p: DockingEvaluator.Params = self.params  # type: ignore[assignment]
        corr = self.last.get("correction")
        base = {"scenario": p.scenario, "docked": False, "success": False, "error_mm": None, "error_deg": None}
        if not isinstance(corr, Correction) or corr.verdict != "ok":
            reasons = corr.reasons if isinstance(corr, Correction) else ["no correction"]
            return {**base, "reason": "; ".join(reasons)}
        robot, parts = self.last.get("robot_truth"), self.last.get("part_truth")
        if not isinstance(robot, PoseStamped) or not isinstance(parts, FrameTransforms):
            return {**base, "reason": "missing truth"}
        truth = {t.child_frame_id.removeprefix(TRUTH_PREFIX): t.T for t in parts.transforms}
        tcp_final = robot.T
        if p.scenario == "assembly":
            return {**base, "docked": True, **self._assembly(truth, tcp_final)}
        T_install = p.install_pose.T() if p.install_pose else None
        if p.scenario == "eye_in_hand":
            want = truth[p.target_part] @ inv(p.target_nominal.T()) @ T_install  # type: ignore[union-attr,index]
            got = tcp_final
        else:
            grasp_true = inv(truth["tcp"]) @ truth[p.held_part]  # type: ignore[index]
            got = tcp_final @ grasp_true
            want = T_install @ p.grasp_nominal.T()  # type: ignore[union-attr,operator]
            if p.scenario == "dual":
                want = truth[p.target_part] @ inv(p.target_nominal.T()) @ want  # type: ignore[union-attr,index]
        t, r = pose_error(got, want)
        return {**base, "docked": True, "error_mm": t * 1e3, "error_deg": float(np.degrees(r)), "success": True}

    def _assembly(self, truth: dict[str, np.ndarray], tcp_final: np.ndarray) -> dict[str, object]:
        p: DockingEvaluator.Params = self.params  # type: ignore[assignment]
        grasp_true = inv(truth["tcp"]) @ truth[p.held_part]  # type: ignore[index]
        return assembly_fit(
            tcp_final @ grasp_true,
            truth[p.base_part],  # type: ignore[index]
            held_workpiece=p.held_workpiece,
            base_workpiece=p.base_workpiece,
            pins=p.pins,
            holes=p.holes,
            clearance_mm=p.clearance_mm,
        )


def assembly_fit(
    T_world_plate: np.ndarray,
    T_world_base: np.ndarray,
    *,
    held_workpiece: str = "planar_plate",
    base_workpiece: str = "base_plate",
    pins: tuple[str, ...] = ("pin1", "pin2"),
    holes: tuple[str, ...] = ("hole1", "hole2"),
    clearance_mm: float = 0.5,
) -> dict[str, object]:
    """Seed 004's criterion for a plate at ``T_world_plate`` over a base at ``T_world_base``.

    Lateral offset (mm) of each pin's root and tip from its hole's axis; ``success`` when every offset
    is under the radial clearance (a pin then enters its hole).
    """
    held, base_part = make_workpiece(held_workpiece), make_workpiece(base_workpiece)
    offsets = []
    for pin, hole in zip(pins, holes, strict=True):
        axis = (T_world_base[:3, :3] @ base_part.feature_axes[hole]).astype(float)
        centre = transform_points(T_world_base, base_part.features[hole])[0]
        for point in (pin, f"{pin}_tip"):
            x = transform_points(T_world_plate, held.features[point])[0] - centre
            offsets.append(float(np.linalg.norm(x - np.dot(x, axis) * axis)) * 1e3)
    worst = max(offsets)
    return {
        "pin_offsets_mm": offsets,
        "error_mm": worst,
        "error_deg": None,
        "success": worst < clearance_mm,
        "clearance_mm": clearance_mm,
    }
