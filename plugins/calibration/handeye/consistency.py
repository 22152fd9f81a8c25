"""Consistency tests between robot and camera data that need no solution: set-up and units.

Set-up / direction test. Relative rotations obey ``R_Aij = R_X R_Bij R_X^T``: robot and camera
rotation *angles* always agree (the readings below cannot be told apart by angles: an inverse or a
conjugate keeps the angle), but the rotation *axes* must be related by one rotation ``R_X``. Under
a wrong reading (eye-in-hand vs eye-to-hand, or camera poses given as T_target_cam) the axes
of different pairs are related by different rotations, or by a reflection. For each of the four
readings, R_X is fitted (Park-Martin) and the median geodesic misfit
``angle(R_Aij^T R_X R_Bij R_X^T)`` over pairs is compared; the chosen reading is declared wrong
when another one fits ``ratio`` times better and the misfit exceeds ``min_mismatch_rad``.

Unit test. The translation of a relative motion along its own rotation axis is a screw invariant:
robot and camera motions of a pair must show the same value, whatever X is. The slope ``s`` of
robot against camera values over all pairs is the length scale between them and must be 1. ``s``
near 1e-3 means the camera is in millimetres, near 1e3 the robot is; a few percent off usually
means a wrong calibration-target size or camera intrinsics (the camera's translations are scaled).
The invariant is the same under both set-ups (their relative robot motions are conjugates of each
other's inverses, and inversion and conjugation keep ``axis . t``), so the test needs no set-up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import rotation_angles
from plugins.calibration.handeye.closed_form import park_martin
from plugins.calibration.handeye.problem import SETUPS, RelativeMotions, Setup, relative_motions

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
    wrong = best != chosen and mismatch[chosen] > ratio * mismatch[best] and mismatch[chosen] > min_mismatch_rad
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


UNIT_T = 4.0  # correlation t statistic of the screw translations below which the scale is unobservable


def mirrored_message(unit: tuple[float, float] | None) -> str | None:
    """What to say when :func:`estimate_unit_scale` (``signed=True``) shows the camera moving
    mirrored to the robot (a clearly negative scale), else None."""
    if unit is None or not (unit[0] < 0.0 and abs(unit[0]) > 5.0 * unit[1]):
        return None
    return (
        f"the camera moved mirrored to the robot (robot translations = {unit[0]:.4g} x camera translations): "
        "mirrored images (a camera or driver set to flip the image?) or the wrong set-up"
    )


def estimate_unit_scale(
    setup: Setup, T_base_tcp: F64, T_cam_target: F64, *, robust: bool = True, signed: bool = False
) -> tuple[float, float] | None:
    """(s, sigma_s) with robot length = s * camera length; None when unobservable.

    Uses a screw invariant that needs no estimate of X: the translation of a relative motion along
    its own rotation axis, ``d = axis . t``, is the same for the robot motion and its hand-eye
    conjugate (``a_A = R_X a_B`` and ``a_A^T (R_A - I) = 0`` in ``(R_A - I) t_X = R_X t_B - t_A``).
    ``s`` is the slope of ``d_A`` against ``d_B`` over pose pairs with 5-170 degrees of rotation;
    ``robust`` uses Cauchy weights (scale from the median residual) so a few bad samples cannot
    fake a unit error. ``sigma_s`` is the weighted least-squares standard error, widened to half the
    gap between ``s`` and the reverse regression's slope: both ``d`` carry noise, which pulls the
    slope of ``d_A`` on ``d_B`` towards 0 and that of ``d_B`` on ``d_A`` (inverted) away from it, and
    the scale lies between the two. With ``signed``, a negative ``s`` (both slopes negative, clearly
    correlated) is returned: the camera moved mirrored to the robot; without, it is None. When
    ``d_A`` and ``d_B`` are not clearly correlated (a correlation t statistic below ``UNIT_T`` over
    the ``n - 1`` independent motions, or slopes of opposite signs), the screw translations are
    noise (poses that orbit the target, e.g. a camera kept looking at a board, have ``d`` near 0)
    and the scale is unobservable: None. Without this a robot pose set of pure
    orbits made the attenuated slope look like a unit error.
    """
    m: RelativeMotions = relative_motions(setup, T_base_tcp, T_cam_target)
    ra = Rotation.from_matrix(m.A[:, :3, :3]).as_rotvec()
    rb = Rotation.from_matrix(m.B[:, :3, :3]).as_rotvec()
    th, tb = np.linalg.norm(ra, axis=1), np.linalg.norm(rb, axis=1)
    # camera angle too: a stale (repeated) observation has no axis
    use = (th > np.deg2rad(5.0)) & (th < np.deg2rad(170.0)) & (tb > np.deg2rad(1.0))
    if np.count_nonzero(use) < 3:
        return None
    d_a = np.einsum("ki,ki->k", ra[use] / th[use, None], m.A[use, :3, 3])
    d_b = np.einsum("ki,ki->k", rb[use] / tb[use, None], m.B[use, :3, 3])
    if np.max(np.abs(d_b)) < 1e-9 or np.max(np.abs(d_a)) < 1e-9:
        return None
    w = np.ones_like(d_a)
    for _ in range(10 if robust else 1):
        s = float(np.sum(w * d_a * d_b) / np.sum(w * d_b * d_b))
        r = d_a - s * d_b
        c = 2.5 * 1.4826 * max(float(np.median(np.abs(r))), 1e-15)
        if robust:
            w = 1.0 / (1.0 + (r / c) ** 2)
    r = d_a - s * d_b
    dof = max(len(r) - 1, 1)
    var = float(np.sum(w * r**2)) / dof / float(np.sum(w * d_b * d_b))
    # pairs share samples, so they are not independent: inflate by the pairs-per-sample ratio
    n = T_base_tcp.shape[0]
    var *= max(len(r) / max(n - 1, 1), 1.0)
    s_reverse = float(np.sum(w * d_a * d_b) / np.sum(w * d_a * d_a))  # camera per robot length
    rho2 = s * s_reverse  # squared correlation of d_A and d_B (through the origin)
    n_eff = max(n - 1, 2)  # independent relative motions
    if s * s_reverse <= 0.0 or rho2 * (n_eff - 1) < UNIT_T**2 * (1.0 - rho2) or (s < 0.0 and not signed):
        return None  # the slopes disagree in sign, or no clear correlation: unobservable
    # (signed) both slopes negative and clearly correlated: the camera moved mirrored to the robot
    # (flipped images, or the wrong set-up), returned as a negative scale for the caller to say so
    return s, max(float(np.sqrt(var)), 0.5 * abs(s - 1.0 / s_reverse))
