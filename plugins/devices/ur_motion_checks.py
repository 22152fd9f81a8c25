"""Checks a UR move target must pass before any motion: rigid, finite, in the workspace, a small step.

Pure functions without SDK or engine state; the ``ur_robot`` stage calls them and refuses the
command (no motion) when one returns a reason. Units: metres and radians (the stage converts the
recipe's mm/degree parameters once).

What is checked
    * Cartesian targets (``move_l``, ``move_j`` to a pose): a finite 4x4 rigid transform
      (``engine.transforms.as_transform``), its position inside the axis-aligned workspace box (base
      frame), and at most ``max_step_m`` / ``max_step_rad`` from the current TCP pose.
      For ``move_l`` the path is the straight segment from the current pose, so a start and a target
      inside the (convex) box keep the whole path inside.
    * Joint targets (``move_j``): finite, one value per joint, inside the joint limits, at most
      ``max_joint_step_rad`` from the current joints on every axis, and (when the controller's
      forward kinematics gives the TCP of the target) that TCP inside the workspace box. A joint move's
      TCP path is not a straight line: the box is checked at the target only, and the step limit
      bounds how far the arm can sweep in between.
    * Speeds and accelerations: 0 in a command means the stage default; a positive value above the
      recipe's maximum is refused (never clamped: the caller asked for something else).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine import transforms as tf

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Workspace:
    """Axis-aligned box in the robot base frame (metres) that TCP targets must lie in."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.min_m, float), np.asarray(self.max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("workspace corners must be finite (x, y, z) in metres")
        if np.any(lo >= hi):
            raise ValueError(f"workspace min {tuple(lo)} must be below max {tuple(hi)} on every axis")

    def outside_reason(self, p: ArrayLike, what: str) -> str | None:
        """None when point *p* is inside the box, else a sentence naming the axis and the excess."""
        p = np.asarray(p, dtype=float).reshape(3)
        for k, axis in enumerate("xyz"):
            if p[k] < self.min_m[k] or p[k] > self.max_m[k]:
                return (
                    f"{what} {axis} = {p[k] * 1000:.1f} mm is outside the workspace "
                    f"[{self.min_m[k] * 1000:.1f}, {self.max_m[k] * 1000:.1f}] mm (base frame)"
                )
        return None


@dataclass(frozen=True)
class MotionLimits:
    """Everything a target is checked against (metres, radians)."""

    workspace: Workspace
    max_step_m: float
    max_step_rad: float
    max_joint_step_rad: float
    joint_min_rad: tuple[float, ...]
    joint_max_rad: tuple[float, ...]


def pose_target_problem(T_target: ArrayLike | None, T_current: ArrayLike, limits: MotionLimits) -> str | None:
    """Why the Cartesian target may not be commanded, or None when it may."""
    if T_target is None:
        return "the command has no target pose T (T_base_tcp)"
    try:
        T = tf.as_transform(T_target, name="target pose T_base_tcp")
    except ValueError as exc:
        return str(exc)
    reason = limits.workspace.outside_reason(T[:3, 3], "target")
    if reason:
        return reason
    dist, angle = tf.pose_error(T_current, T)
    if dist > limits.max_step_m:
        return (
            f"target is {dist * 1000:.1f} mm from the current TCP pose; the step limit is "
            f"{limits.max_step_m * 1000:.1f} mm (max_step_m)"
        )
    if angle > limits.max_step_rad:
        return (
            f"target orientation differs by {math.degrees(angle):.2f} deg from the current TCP pose; the step "
            f"limit is {math.degrees(limits.max_step_rad):.2f} deg (max_step_deg)"
        )
    return None


def joint_target_problem(q_target: ArrayLike | None, q_current: ArrayLike, limits: MotionLimits) -> str | None:
    """Why the joint target may not be commanded (before the workspace check of its TCP), or None."""
    if q_target is None:
        return "the command has no joint target"
    q = np.asarray(q_target, dtype=float).reshape(-1)
    q0 = np.asarray(q_current, dtype=float).reshape(-1)
    if q.shape != q0.shape:
        return f"joint target has {q.size} values, the robot has {q0.size} joints"
    if not np.all(np.isfinite(q)):
        return "joint target contains NaN or infinity"
    lo, hi = np.asarray(limits.joint_min_rad, float), np.asarray(limits.joint_max_rad, float)
    for i in range(q.size):
        if q[i] < lo[i] or q[i] > hi[i]:
            return (
                f"joint {i + 1} target {math.degrees(q[i]):.2f} deg is outside its limits "
                f"[{math.degrees(lo[i]):.1f}, {math.degrees(hi[i]):.1f}] deg"
            )
    step = np.abs(q - q0)
    i = int(np.argmax(step))
    if step[i] > limits.max_joint_step_rad:
        return (
            f"joint {i + 1} would move {math.degrees(step[i]):.2f} deg; the step limit is "
            f"{math.degrees(limits.max_joint_step_rad):.2f} deg (max_joint_step_deg)"
        )
    return None


def resolve_rate(requested: float, default: float, maximum: float, what: str, unit: str) -> tuple[float, str | None]:
    """The speed/acceleration to use: *default* for 0, *requested* if within *maximum*, else a refusal."""
    if not math.isfinite(requested) or requested < 0:
        return default, f"{what} {requested} {unit} is not a non-negative number"
    if requested == 0:
        return default, None
    if requested > maximum:
        return default, f"{what} {requested:g} {unit} exceeds the configured maximum {maximum:g} {unit}"
    return requested, None
