"""A simulated robot controller that drives a cell service the way a real robot program does.

Per part (:meth:`SimController.cycle`): the next part arrives at a random offset (the simulated
camera's ``place`` service), the controller moves its robot to the photo pose (the simulated robot's
``move`` service), asks ``locate`` with its own flange pose, and on ``ok`` moves to the corrected
install pose the reply gives; then the truth says how well it docked: the TCP against
``P_true P_nominal^-1 T_install`` (the docking evaluator's eye-in-hand criterion,
plugins.sim.stages.evaluation). Any other status: the controller moves nothing and takes the next part.

Used by the tests of the cell service and by benchmarks/cell_service.py; it talks to the service over
its API (engine.run.cell.client) and to the simulated devices over their stage services, as a robot
program and a part feeder would, never through the service's internals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from engine.messages import Message, Request, RobotCommand, codec
from engine.run.cell.client import CellClient, new_id
from engine.run.cell.protocol import pose_doc, pose_from_doc
from engine.transforms import T_from_Rt, pose_error
from engine.transport.bus import service_key

# the default cell (recipes/cell_service_sim.yaml)
PHOTO_POSE = np.array([[0, 1, 0, -0.49], [1, 0, 0, -0.14], [0, 0, -1, 0.45], [0, 0, 0, 1]], dtype=float)
PART_POSE = T_from_Rt(Rotation.from_euler("z", 10, degrees=True).as_matrix(), (-0.49, -0.08, 0.0))
INSTALL_POSE = np.array([[0, 1, 0, -0.47], [1, 0, 0, -0.07], [0, 0, -1, 0.15], [0, 0, 0, 1]], dtype=float)


@dataclass
class CycleOutcome:
    """One part: the reply's status and cycle, the true docking error (None when nothing docked)."""

    part: int
    status: str
    cycle: int
    error_mm: float | None = None
    error_deg: float | None = None
    timing_ms: dict[str, float] | None = None


class SimController:
    """Drives cell *client*'s simulated cell: robot stage *robot*, camera stage *camera*, part *part*."""

    def __init__(
        self,
        client: CellClient,
        *,
        seed: int = 0,
        robot: str = "robot",
        camera: str = "camera",
        part: str = "part",
        offset_mm: float = 10.0,
        offset_deg: float = 5.0,
        dock: bool = True,
    ) -> None:
        self.client = client
        self.rng = np.random.default_rng(seed)
        self.robot, self.camera, self.part = robot, camera, part
        self.offset_mm, self.offset_deg = offset_mm, offset_deg
        self.dock = dock
        self.parts = 0

    def _device(self, stage: str, service: str, request: Message, timeout_s: float = 30.0) -> Any:
        payload, att = codec.encode(request)
        key = service_key(self.client.cell, stage, service)
        answers = self.client._bus.request(key, payload, att, timeout_s)
        answer = answers[0]
        if answer.error is not None:
            raise RuntimeError(f"{stage}.{service}: {answer.error}")
        return codec.decode(answer.payload, codec.decode_envelope(answer.attachment))

    def _move(self, T: np.ndarray, kind: str) -> np.ndarray:
        reply = self._device(self.robot, "move", RobotCommand(command_id=new_id("sim-move"), kind=kind, T=T))
        if not reply.ok:
            raise RuntimeError(f"the simulated robot refused {kind}: {reply.error}")
        return np.asarray(reply.T, dtype=float)

    def next_part(self) -> np.ndarray:
        """Put the next part at a random offset from its nominal pose; its true pose."""
        dxy = self.rng.uniform(-self.offset_mm, self.offset_mm, 2) / 1e3
        dyaw = self.rng.uniform(-self.offset_deg, self.offset_deg)
        offset = T_from_Rt(Rotation.from_euler("z", dyaw, degrees=True).as_matrix(), (dxy[0], dxy[1], 0.0))
        T_part = offset @ PART_POSE
        self._device(self.camera, "place", Request(command="place", args={"part": self.part, "pose": pose_doc(T_part)}))
        return T_part

    def cycle(self) -> CycleOutcome:
        """One part, as a robot program does it (see the module docstring)."""
        self.parts += 1
        T_part = self.next_part()
        T_photo = self._move(PHOTO_POSE, "move_j")
        reply = self.client.locate(T_photo)
        outcome = CycleOutcome(self.parts, str(reply["status"]), int(reply["cycle"]), timing_ms=reply["timing_ms"])
        if reply["status"] != "ok" or not self.dock:
            return outcome
        target = pose_from_doc(reply["result"]["parts"][0]["targets"]["install"], "install")
        self._move(target, "move_j")
        truth = self._device(self.robot, "truth", Request(command="truth"))
        want = T_part @ np.linalg.inv(PART_POSE) @ INSTALL_POSE
        t, r = pose_error(np.asarray(truth.T, dtype=float), want)
        outcome.error_mm, outcome.error_deg = t * 1e3, float(np.degrees(r))
        return outcome
