"""Motion-set analysis BEFORE solving: can these robot poses determine the hand-eye transform?

Both the rotation and the translation of X are fixed by relative robot rotations through
``(I - R_Aij)``: a pair turns every direction ``e`` by
``|(I - R_Aij) e| = 2 sin(theta/2) sin(angle(axis, e))``.
The *rotation excitation* matrix

    H = mean over pose pairs of (I - R_Aij)^T (I - R_Aij) = mean 2 (1 - cos theta) (I - a a^T)

has eigenvalues ``lambda_k``; ``sqrt(lambda_k)`` is the RMS angle (chord, rad) by which the pairs turn
the principal direction ``e_k``. A direction that is hardly turned is the axis every motion rotates
about: rotation about it and translation along it are then unobservable (Tsai-Lenz / Park-Martin
identifiability: at least two motions with non-parallel axes).

Verdicts: ``degenerate`` for fewer than ``min_poses`` poses, a largest relative rotation below
``min_total_rotation_deg``, or an excitation below ``min_excitation_deg`` in some direction;
``warning`` for an excitation below ``weak_excitation_deg`` or fewer than ``few_poses`` poses.
The advice names the missing rotation axes in the frame of X's parent (tcp for eye-in-hand, base
for eye-to-hand). Seed 000: 10-20 poses, rotations of about +-30 degrees, not about one axis only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from plugins.calibration.handeye.problem import Setup, frames_of, relative_motions

F64 = NDArray[np.float64]

__all__ = ["MotionReport", "MotionThresholds", "analyse_motions"]


@dataclass(frozen=True)
class MotionThresholds:
    """Thresholds of the motion analysis (degrees, counts)."""

    min_poses: int = 3
    few_poses: int = 6
    min_total_rotation_deg: float = 5.0
    min_excitation_deg: float = 2.0
    weak_excitation_deg: float = 8.0


@dataclass
class MotionReport:
    """Outcome of :func:`analyse_motions`."""

    verdict: str  # "ok" | "warning" | "degenerate"
    reasons: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    weakest_direction: F64 | None = None


def _fmt(v: F64) -> str:
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def _perpendiculars(e: F64) -> tuple[F64, F64]:
    """Two unit vectors perpendicular to e, the first as close as possible to a frame axis."""
    axis = np.eye(3)[int(np.argmin(np.abs(e)))]
    p1 = axis - (axis @ e) * e
    p1 /= np.linalg.norm(p1)
    return p1, np.cross(e, p1)


def analyse_motions(
    setup: Setup, T_base_tcp: F64, T_cam_target: F64, thresholds: MotionThresholds | None = None
) -> MotionReport:
    """Analyse the robot motions of validated samples; see the module docstring."""
    th = thresholds or MotionThresholds()
    frames = frames_of(setup)
    mover = "tool (flange)" if setup == "eye_in_hand" else "flange with the target"
    n = int(T_base_tcp.shape[0])
    rep = MotionReport(verdict="ok", metrics={"n_poses": float(n)})
    if n < th.min_poses:
        rep.verdict = "degenerate"
        rep.reasons.append(
            f"too few poses: {n} (at least {th.min_poses} are needed for 12 unknowns, "
            "because one relative motion leaves the rotation about its axis free)"
        )
        rep.advice.append(
            f"collect at least {th.min_poses} poses, better 10-20, rotating the {mover} by 20-30 degrees "
            "about at least two different axes between poses"
        )
        return rep

    m = relative_motions(setup, T_base_tcp, T_cam_target)
    rotvec = Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec()
    theta = np.linalg.norm(rotvec, axis=1)
    axes = rotvec / np.maximum(theta, 1e-300)[:, None]
    weight = 2.0 * (1.0 - np.cos(theta))
    H = np.einsum("k,kij->ij", weight, np.eye(3) - np.einsum("ki,kj->kij", axes, axes)) / len(theta)
    lam, vec = np.linalg.eigh(H)
    excitation = np.sqrt(np.clip(lam, 0.0, None))
    e_weak = vec[:, 0] * (1.0 if vec[np.argmax(np.abs(vec[:, 0])), 0] > 0 else -1.0)
    rep.weakest_direction = e_weak
    max_rot = float(theta.max())
    rep.metrics.update(
        {
            "max_relative_rotation_rad": max_rot,
            "rms_relative_rotation_rad": float(np.sqrt(np.mean(theta**2))),
            "excitation_min_rad": float(excitation[0]),
            "excitation_mid_rad": float(excitation[1]),
            "excitation_max_rad": float(excitation[2]),
        }
    )
    p1, p2 = _perpendiculars(e_weak)
    frame = frames.x_parent

    if max_rot < np.deg2rad(th.min_total_rotation_deg):
        rep.verdict = "degenerate"
        rep.reasons.append(
            "too little rotation: the largest rotation between any two poses is "
            f"{np.rad2deg(max_rot):.2f} deg (< {th.min_total_rotation_deg} deg); translations alone do not "
            "determine the hand-eye rotation"
        )
        rep.advice.append(f"rotate the {mover} by 20-30 degrees between poses, about at least two different axes")
        return rep

    ex_min = float(np.rad2deg(excitation[0]))
    if ex_min < th.min_excitation_deg:
        rep.verdict = "degenerate"
        rep.reasons.append(
            f"all relative rotations are about (nearly) one axis, {_fmt(e_weak)} in the {frame} frame: "
            f"that direction is turned by only {ex_min:.2f} deg RMS (< {th.min_excitation_deg} deg), so the "
            f"rotation about it and the translation along it are not determined"
        )
        rep.advice.append(
            f"add poses that tilt the {mover} by 20-30 degrees about an axis perpendicular to {_fmt(e_weak)} "
            f"({frame} frame), e.g. about {_fmt(p1)} and {_fmt(p2)}"
        )
    elif ex_min < th.weak_excitation_deg:
        rep.verdict = "warning"
        rep.reasons.append(
            f"weak rotation diversity: direction {_fmt(e_weak)} ({frame} frame) is turned by only "
            f"{ex_min:.1f} deg RMS (< {th.weak_excitation_deg} deg); expect amplified errors about/along it"
        )
        rep.advice.append(
            f"add poses tilting the {mover} by 20-30 degrees about {_fmt(p1)} or {_fmt(p2)} ({frame} frame)"
        )
    if n < th.few_poses and rep.verdict != "degenerate":
        rep.verdict = "warning"
        rep.reasons.append(f"only {n} poses: outliers cannot be detected reliably (10-20 recommended)")
        rep.advice.append("collect 10-20 poses spread over the working volume")
    return rep
