"""The per-sample features of a kinematic gap problem: what the residuals are binned along.

Each joint angle, the gravity torque of each joint (payload included), each approach direction,
time, temperature, payload, tool speed, range, and where the tool is in the robot's workspace
(x, y, z in the base frame, marked ``spatial``: the residual-structure test of :mod:`plugins.model_gap.core.structure`
fits a smooth field over them; and the distance from the base axis).
"""

from __future__ import annotations

import numpy as np

from plugins.model_gap.core.interfaces import Feature
from plugins.model_gap.data import GapData
from plugins.robot.kinematics import RobotModel


def features(
    data: GapData, q: np.ndarray, nominal: RobotModel, tau: np.ndarray | None, tool_speed_m_s: np.ndarray | None
) -> list[Feature]:
    """Every feature of the module docstring that the data have: *q* the joint angles (n x dof, rad),
    *tau* the gravity torques (n x dof, N m) or None, *tool_speed_m_s* the tool speed or None."""
    s = data.samples
    dof = q.shape[1]
    out = [Feature(f"q{j + 1}", f"joint {j + 1} angle", "deg", np.degrees(q[:, j])) for j in range(dof)]
    if tau is not None:
        for j in range(dof):
            if np.ptp(tau[:, j]) > 1e-6:
                out.append(Feature(f"tau{j + 1}", f"gravity torque joint {j + 1}", "N m", tau[:, j]))
    if s.direction is not None:
        for j in range(dof):
            out.append(Feature(f"dir{j + 1}", f"approach direction joint {j + 1}", "", s.direction[:, j], True))
    for name, label, unit, v in (
        ("t_s", "time", "s", s.t_s),
        ("temp_c", "temperature", "deg C", s.temp_c),
        ("payload_kg", "payload", "kg", s.payload_kg),
    ):
        if v is not None and np.ptp(v) > 0:
            out.append(Feature(name, label, unit, np.asarray(v, dtype=float), bool(np.unique(v).size <= 3)))
    if tool_speed_m_s is not None:
        out.append(Feature("speed", "tool speed", "mm/s", tool_speed_m_s * 1e3))
    if data.range_m is not None:
        out.append(Feature("range", "range (depth)", "mm", data.range_m * 1e3))
    p_base = nominal.fk(q, frame="base")[:, :3, 3] * 1e3
    for i, ax in enumerate("xyz"):
        out.append(Feature(f"work_{ax}", f"workspace {ax} (robot base)", "mm", p_base[:, i], spatial=True))
    out.append(Feature("reach", "distance from the base axis", "mm", np.linalg.norm(p_base[:, :2], axis=1)))
    return out
