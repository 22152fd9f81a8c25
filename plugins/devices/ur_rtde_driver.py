"""A thin, checked wrapper around ur-rtde's RTDEReceiveInterface and RTDEControlInterface.

Owns the connection to one UR controller and the translation between vgr and the SDK: UR pose
vectors ``[x, y, z, rx, ry, rz]`` (m, rotation vector) are converted only by
``plugins.vendor_poses.T_from_ur`` / ``ur_from_T``; joint vectors are plain lists of radians. It says in
words what is wrong with the controller (protective stop, emergency stop, not powered, control
script not running / remote control off, connection lost), which the stage puts in its refusals.

The SDK modules are passed in (``rtde_receive`` and ``rtde_control``, imported lazily by the stage),
so tests hand in fakes of the same interface. Moves are blocking (``asynchronous=False``): the call
returns when the controller reports the move finished or failed.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins import vendor_poses

F64 = NDArray[np.float64]

ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
ROBOT_MODE_RUNNING = 7
SAFETY_MODES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
SAFETY_MODES_OK = (1, 2)  # NORMAL, REDUCED: the controller accepts motion


class URConnectionError(RuntimeError):
    """The controller could not be reached or refused the RTDE session; the message says what to check."""


def _connection_hint(ip: str, exc: BaseException, control: bool) -> str:
    text = str(exc)
    if "remote control" in text.lower():
        return (
            f"the UR controller at {ip} is not in remote control ({text}). On the teach pendant enable "
            "Settings > System > Remote Control and switch the pendant to Remote mode, or set "
            "control: false for a read-only connection"
        )
    checks = [
        f"the robot is powered on and reachable (ping {ip})",
        f"'{ip}' is the controller's address (PolyScope: Settings > System > Network)",
        "this computer is on the robot's subnet and no firewall blocks TCP ports 29999, 30001-30004",
        "no other RTDE client holds the controller's input registers (another driver, a URCap)",
    ]
    if control:
        checks.append("the robot is in remote control (PolyScope 5.6+) so the control script can be uploaded")
    return f"cannot connect to the UR controller at {ip}: {type(exc).__name__}: {text}. Check: " + "; ".join(checks)


@dataclass(frozen=True)
class URState:
    """One reading of the controller: joints (rad), T_base_tcp, modes and stop flags."""

    q: F64
    T_base_tcp: F64
    robot_mode: int
    safety_mode: int
    protective_stopped: bool
    emergency_stopped: bool


class URDriver:
    """Connection to one UR controller through ur-rtde (receive always, control unless read-only)."""

    def __init__(
        self,
        ip: str,
        *,
        rtde_receive: ModuleType,
        rtde_control: ModuleType | None,
        frequency_hz: float = -1.0,
    ) -> None:
        self.ip = ip
        self.receive: Any = None
        self.control: Any = None
        try:
            self.receive = rtde_receive.RTDEReceiveInterface(ip, frequency_hz)
            if rtde_control is not None:
                self.control = rtde_control.RTDEControlInterface(ip, frequency_hz)
        except Exception as exc:
            self.close()
            raise URConnectionError(_connection_hint(ip, exc, rtde_control is not None)) from exc

    @property
    def read_only(self) -> bool:
        return self.control is None

    # -- state ---------------------------------------------------------------------------------
    def state(self) -> URState:
        """Read joints, TCP pose and modes; raises URConnectionError when the data is unusable."""
        r = self.receive
        if r is None or not r.isConnected():
            raise URConnectionError(f"not connected to the UR controller at {self.ip} (RTDE receive link down)")
        q = np.asarray(r.getActualQ(), dtype=float)
        pose = np.asarray(r.getActualTCPPose(), dtype=float)
        if q.shape != (6,) or pose.shape != (6,) or not (np.all(np.isfinite(q)) and np.all(np.isfinite(pose))):
            raise URConnectionError(
                f"the UR controller at {self.ip} sent unusable state (joints {q.tolist()}, TCP pose {pose.tolist()})"
            )
        return URState(
            q=q,
            T_base_tcp=vendor_poses.T_from_ur(pose),
            robot_mode=int(r.getRobotMode()),
            safety_mode=int(r.getSafetyMode()),
            protective_stopped=bool(r.isProtectiveStopped()),
            emergency_stopped=bool(r.isEmergencyStopped()),
        )

    def motion_blocker(self) -> str | None:
        """Why the controller cannot move now (in words, with what to do), or None when it can."""
        if self.control is None:
            return "the robot is connected read-only (control: false); moves are refused"
        if not self.control.isConnected() or not self.receive.isConnected():
            return f"not connected to the UR controller at {self.ip} (RTDE link down); restart the run to reconnect"
        try:
            s = self.state()
        except URConnectionError as exc:
            return str(exc)
        if s.emergency_stopped:
            return "the robot is emergency-stopped: release the e-stop and re-enable the robot on the pendant"
        if s.protective_stopped:
            return "the robot is in a protective stop: find the cause, unlock the protective stop on the pendant"
        if s.safety_mode not in SAFETY_MODES_OK:
            name = SAFETY_MODES.get(s.safety_mode, f"unknown ({s.safety_mode})")
            return f"the controller's safety mode is {name}, not NORMAL/REDUCED; resolve it on the pendant"
        if s.robot_mode != ROBOT_MODE_RUNNING:
            name = ROBOT_MODES.get(s.robot_mode, f"unknown ({s.robot_mode})")
            return f"robot mode is {name}, not RUNNING: power the arm on and release the brakes"
        if not self.control.isProgramRunning():
            return (
                "the ur-rtde control script is not running on the controller (a program was started or stopped "
                "on the pendant, or remote control was switched off); restart the run to upload it again"
            )
        return None

    # -- motion (blocking) -----------------------------------------------------------------------
    def move_l(self, T_base_tcp: ArrayLike, speed: float, acceleration: float) -> bool:
        return bool(self.control.moveL(vendor_poses.ur_from_T(T_base_tcp).tolist(), speed, acceleration, False))

    def move_j(self, q: ArrayLike, speed: float, acceleration: float) -> bool:
        return bool(self.control.moveJ(np.asarray(q, dtype=float).tolist(), speed, acceleration, False))

    def inverse_kinematics(self, T_base_tcp: ArrayLike, q_near: ArrayLike) -> F64 | None:
        """Joints reaching *T_base_tcp* by the controller's own IK, the solution nearest *q_near*
        (no motion); None when it gives none. The caller checks them (limits, step, FK) before moving."""
        try:
            q = self.control.getInverseKinematics(
                vendor_poses.ur_from_T(T_base_tcp).tolist(), np.asarray(q_near, dtype=float).tolist()
            )
        except RuntimeError:  # ur-rtde raises when the controller finds no solution
            return None
        q = np.asarray(q, dtype=float)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            return None
        return q

    def forward_kinematics(self, q: ArrayLike) -> F64 | None:
        """T_base_tcp of joints *q* by the controller's calibrated model and active TCP (no motion)."""
        pose = np.asarray(self.control.getForwardKinematics(np.asarray(q, dtype=float).tolist()), dtype=float)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            return None
        return vendor_poses.T_from_ur(pose)

    def stop(self, joint_deceleration: float) -> None:
        """Decelerate the joints to zero (stopJ); harmless when nothing moves."""
        if self.control is not None:
            self.control.stopJ(joint_deceleration, False)

    def close(self) -> None:
        """Stop the control script and disconnect both interfaces (safe to call twice)."""
        control, receive = self.control, self.receive
        self.control = self.receive = None
        if control is not None:
            try:
                control.stopScript()
            finally:
                control.disconnect()
        if receive is not None:
            receive.disconnect()
