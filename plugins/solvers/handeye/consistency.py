"""Consistency tests between robot and camera data that need no solution: set-up and units.

Set-up / direction test. Relative rotations obey ``R_Aij = R_X R_Bij R_X^T``: robot and camera
rotation *angles* always agree (the readings below cannot be told apart by angles: an inverse or a
conjugate keeps the angle), but the rotation *axes* must be related by one rotation ``R_X``. Under
a wrong reading (eye-in-hand vs eye-to-hand, or camera poses given as T_target_cam) the axes
of different pairs are related by different rotations, or by a reflection. For each of the four
readings, R_X is fitted (Park-Martin) and the median geodesic misfit
``angle(R_Aij^T R_X R_Bij R_X^T)`` over pairs is compared; the chosen reading is declared wrong
when another one fits ``ratio`` times better and the misfit exceeds ``min_mismatch_rad``.

Unit test. Rotations do not depend on length units, so a rotation-only estimate of X (Park-Martin)
is valid even with mixed units; the translation equations ``(R_Aij - I) t_X = s R_X t_Bij - t_Aij``
then give the scale ``s`` between camera and robot lengths, which must be 1. ``s`` near 1e-3 means
the camera is in millimetres, near 1e3 the robot is; a few percent off usually means a wrong
calibration-target size or camera intrinsics (the camera's translations are scaled).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from plugins.solvers.handeye.closed_form import park_martin
from plugins.solvers.handeye.lie import rotation_angles
from plugins.solvers.handeye.problem import SETUPS, RelativeMotions, Setup, relative_motions

F64 = NDArray[np.float64]

__all__ = ["SetupCheck", "check_setup_consistency", "estimate_unit_scale"]


@dataclass
class SetupCheck:
    """Median rotation misfit (rad) of the relative motions under each reading (set-up, camera inverted)."""

    mismatch: dict[tuple[str, bool], float]
    chosen: tuple[str, bool]
    best: tuple[str, bool]
    wrong: bool
    message: str = ""


def check_setup_consistency(
    setup: Setup,
    T_base_tcp: F64,
    T_cam_target: F64,
    *,
    ratio: float = 5.0,
    min_mismatch_rad: float = float(np.deg2rad(0.5)),
) -> SetupCheck:
    """Compare the four readings; ``wrong`` when the chosen one is clearly worse than another."""
    mismatch: dict[tuple[str, bool], float] = {}
    for s in SETUPS:
        m = relative_motions(s, T_base_tcp, T_cam_target)
        R_X = park_martin(m)[:3, :3]
        misfit = rotation_angles(np.transpose(m.A[:, :3, :3], (0, 2, 1)) @ R_X @ m.B[:, :3, :3] @ R_X.T)
        mismatch[(s, False)] = float(np.median(misfit))
    chosen = (setup, False)
    best = min(mismatch, key=mismatch.__getitem__)
    wrong = (
        best != chosen and mismatch[chosen] > ratio * mismatch[best] and mismatch[chosen] > min_mismatch_rad
    )
    message = ""
    if wrong:
        message = (
            f"robot and camera rotation axes do not fit one hand-eye rotation for {setup}: median misfit "
            f"{np.rad2deg(mismatch[chosen]):.2f} deg, but {np.rad2deg(mismatch[best]):.3f} deg for "
            f"{best[0]}. Either the set-up is {best[0]}, or the camera poses are inverted (T_target_cam "
            "given instead of T_cam_target), or the robot poses are inverted (T_tcp_base instead of "
            "T_base_tcp): these give the same equations"
        )
    return SetupCheck(mismatch=mismatch, chosen=chosen, best=best, wrong=wrong, message=message)


def estimate_unit_scale(setup: Setup, T_base_tcp: F64, T_cam_target: F64) -> tuple[float, float] | None:
    """(s, sigma_s) with robot length = s * camera length, from the AX = XB translations.

    None when the camera translations carry no scale information (the column of ``s`` is nearly
    dependent on those of ``t_X``). ``sigma_s`` is the least-squares standard error (residual-based).
    """
    m: RelativeMotions = relative_motions(setup, T_base_tcp, T_cam_target)
    R_X = park_martin(m)[:3, :3]
    lhs = np.zeros((len(m.A), 3, 4))
    lhs[:, :, :3] = m.A[:, :3, :3] - np.eye(3)
    lhs[:, :, 3] = -(m.B[:, :3, 3] @ R_X.T)
    L = lhs.reshape(-1, 4)
    rhs = -m.A[:, :3, 3].reshape(-1)
    col_norm = np.linalg.norm(L, axis=0)
    if col_norm[3] < 1e-9 or np.linalg.cond(L / np.maximum(col_norm, 1e-300)) > 1e6:
        return None
    sol, *_ = np.linalg.lstsq(L, rhs, rcond=None)
    dof = max(L.shape[0] - 4, 1)
    s2 = float(np.sum((L @ sol - rhs) ** 2)) / dof
    cov = s2 * np.linalg.inv(L.T @ L)
    return float(sol[3]), float(np.sqrt(max(cov[3, 3], 0.0)))
