"""A fake UR controller behind fake ``rtde_receive`` / ``rtde_control`` modules (ur-rtde's interface).

Only the calls vgr makes exist, with ur-rtde's names and argument order (checked against the
installed ur_rtde 1.6 docstrings: ``moveL(pose, speed, acceleration, asynchronous)``, etc.). The arm
is the shipped nominal UR5e model (plugins.sim): moves set the joints and the TCP consistently, FK
answers like the controller's ``getForwardKinematics``. Every call is logged in ``calls`` so tests
can assert that a refused command never reached a move function.
"""

from __future__ import annotations

import json
import sys
import types
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from plugins import vendor_poses
from plugins.robot.model_file import load_robot_model

UR5E_HOME = np.array([0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
MOVE_CALLS = ("moveL", "moveJ", "moveJ_IK")
IP = "192.168.56.101"  # the address the tests give ur_robot
WORKSPACE = "workspace_min_m: [-0.8, -0.6, 0.05], workspace_max_m: [0.2, 0.6, 0.8]"  # ur_robot's box, recipe YAML


@dataclass
class FakeURController:
    """State of the pretend controller shared by the receive and control interfaces."""

    q: np.ndarray = field(default_factory=lambda: UR5E_HOME.copy())
    robot_mode: int = 7  # RUNNING
    safety_mode: int = 1  # NORMAL
    protective_stopped: bool = False
    emergency_stopped: bool = False
    program_running: bool = True
    connected: bool = True
    receive_connect_error: Exception | None = None
    control_connect_error: Exception | None = None
    next_move_fails: str | None = None  # "protective_stop" | "returns_false" | "raises" | "stops_short"
    fk_fails: bool = False
    ik_answer: str = "solve"  # "solve" | "raises" (no solution) | "elsewhere" (joints that do not reach the pose)
    calls: list[tuple[str, tuple[Any, ...]]] = field(default_factory=list)
    hosts: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.model = load_robot_model("ur5e")

    # pose in UR vector form, as the controller reports it
    def tcp_vector(self) -> list[float]:
        return vendor_poses.ur_from_T(self.model.fk(self.q, frame="base")).tolist()

    def move_calls(self) -> list[tuple[str, tuple[Any, ...]]]:
        return [c for c in self.calls if c[0] in MOVE_CALLS]

    def _fail(self) -> bool | None:
        mode, self.next_move_fails = self.next_move_fails, None
        if mode == "protective_stop":
            self.protective_stopped, self.safety_mode = True, 3
            return False
        if mode == "returns_false":
            return False
        if mode == "raises":
            raise RuntimeError("RTDE control script is not running!")
        if mode == "stops_short":
            self.q = self.q + np.radians([0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
            return True
        return None

    def go_to_pose(self, pose: list[float]) -> bool:
        res = self.model.ik(vendor_poses.T_from_ur(pose), self.q)
        if not res.success:
            return False
        self.q = np.asarray(res.q, dtype=float)
        return True


def photo_pose(ctl: FakeURController, dx: float = 0.01) -> np.ndarray:
    """A photo pose *dx* (m) along base x from where the fake robot's TCP stands."""
    T = vendor_poses.T_from_ur(ctl.tcp_vector())
    T[0, 3] += dx
    return T


def matrix_yaml(T: np.ndarray) -> str:
    """*T* as a recipe YAML matrix."""
    return json.dumps(np.round(T, 12).tolist())


def make_modules(ctl: FakeURController) -> tuple[types.ModuleType, types.ModuleType]:
    """Fake ``rtde_receive`` and ``rtde_control`` modules driving *ctl*."""

    class RTDEReceiveInterface:
        def __init__(self, hostname: str, frequency: float = -1.0, *args: Any) -> None:
            ctl.calls.append(("RTDEReceiveInterface", (hostname, frequency)))
            if ctl.receive_connect_error is not None:
                raise ctl.receive_connect_error
            ctl.hosts.append(hostname)

        def isConnected(self) -> bool:
            return ctl.connected

        def getActualQ(self) -> list[float]:
            return ctl.q.tolist()

        def getActualTCPPose(self) -> list[float]:
            return ctl.tcp_vector()

        def getRobotMode(self) -> int:
            return ctl.robot_mode

        def getSafetyMode(self) -> int:
            return ctl.safety_mode

        def isProtectiveStopped(self) -> bool:
            return ctl.protective_stopped

        def isEmergencyStopped(self) -> bool:
            return ctl.emergency_stopped

        def disconnect(self) -> None:
            ctl.calls.append(("receive.disconnect", ()))

    class RTDEControlInterface:
        def __init__(self, hostname: str, frequency: float = -1.0, *args: Any) -> None:
            ctl.calls.append(("RTDEControlInterface", (hostname, frequency)))
            if ctl.control_connect_error is not None:
                raise ctl.control_connect_error

        def isConnected(self) -> bool:
            return ctl.connected

        def isProgramRunning(self) -> bool:
            return ctl.program_running

        def moveL(self, pose: list[float], speed: float = 0.25, acceleration: float = 1.2, asynchronous=False) -> bool:
            ctl.calls.append(("moveL", (list(pose), speed, acceleration, asynchronous)))
            failed = ctl._fail()
            return failed if failed is not None else ctl.go_to_pose(pose)

        def moveJ_IK(self, pose: list[float], speed=1.05, acceleration=1.4, asynchronous=False) -> bool:
            ctl.calls.append(("moveJ_IK", (list(pose), speed, acceleration, asynchronous)))
            failed = ctl._fail()
            return failed if failed is not None else ctl.go_to_pose(pose)

        def moveJ(self, q: list[float], speed: float = 1.05, acceleration: float = 1.4, asynchronous=False) -> bool:
            ctl.calls.append(("moveJ", (list(q), speed, acceleration, asynchronous)))
            failed = ctl._fail()
            if failed is not None:
                return failed
            ctl.q = np.asarray(q, dtype=float)
            return True

        def getInverseKinematics(self, x: list[float], qnear: list[float] | None = None, *args: float) -> list[float]:
            ctl.calls.append(("getInverseKinematics", (list(x), qnear)))
            res = ctl.model.ik(vendor_poses.T_from_ur(x), np.asarray(qnear if qnear else ctl.q))
            if ctl.ik_answer == "raises" or not res.success:
                raise RuntimeError("getInverseKinematics: no solution")
            q = np.asarray(res.q, dtype=float)
            if ctl.ik_answer == "elsewhere":
                q = q + np.radians([0.0, 0.0, 0.0, 0.0, 0.0, 0.5])  # a wrist turned by half a degree
            return q.tolist()

        def getForwardKinematics(self, q: list[float] | None = None, tcp_offset: list[float] | None = None):
            ctl.calls.append(("getForwardKinematics", (q,)))
            if ctl.fk_fails:
                return []
            return vendor_poses.ur_from_T(ctl.model.fk(np.asarray(q if q else ctl.q), frame="base")).tolist()

        def stopJ(self, a: float = 2.0, asynchronous: bool = False) -> None:
            ctl.calls.append(("stopJ", (a, asynchronous)))

        def stopScript(self) -> None:
            ctl.calls.append(("stopScript", ()))

        def disconnect(self) -> None:
            ctl.calls.append(("control.disconnect", ()))

    receive = types.ModuleType("rtde_receive")
    receive.RTDEReceiveInterface = RTDEReceiveInterface  # type: ignore[attr-defined]
    control = types.ModuleType("rtde_control")
    control.RTDEControlInterface = RTDEControlInterface  # type: ignore[attr-defined]
    return receive, control


def install(monkeypatch: Any, ctl: FakeURController) -> None:
    """Make ``import rtde_receive`` / ``import rtde_control`` return the fakes for this test."""
    receive, control = make_modules(ctl)
    monkeypatch.setitem(sys.modules, "rtde_receive", receive)
    monkeypatch.setitem(sys.modules, "rtde_control", control)
