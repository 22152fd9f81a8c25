"""The algebra of vision-guided correction (seed 000), derived in vgr's frame convention.

Conventions: ``T_a_b`` maps points from b to a. The matchers return ``T_match`` mapping points of
the CURRENT capture onto the TEMPLATE: ``p_template = T_match @ p_current`` (seed 000's
``ICP(P_current, P_template)``), so ``T_match = I`` when the scene looks as it did when the
template was taken.

Eye-in-hand (camera on the flange, ``T_tcp_cam``; the part lies in the cell at pose P, it was at P0
for the template, taken from the photo pose T0). With C = T_base_tcp T_tcp_cam::

    p_template = C0^-1 P0 x,  p_current = C^-1 P x   =>  T_match = C0^-1 P0 P^-1 C
    the view matches when C_new = P P0^-1 C0 = C T_match^-1
    =>  T_base_tcp_new = T_base_tcp @ T_delta,  T_delta = T_tcp_cam T_match^-1 T_tcp_cam^-1   (tool frame)

Eye-to-hand (camera fixed at ``T_base_cam``; the part is in the gripper with grasp G, it had grasp
G0 for the template, taken at T0)::

    T_match = C^-1 T0 G0 G^-1 T^-1 C    the view matches when T_new = T0 G0 G^-1 = C T_match C^-1 T
    =>  T_base_tcp_new = T_delta @ T_base_tcp,  T_delta = T_base_cam T_match T_base_cam^-1   (base frame)

Docking, with T_start the photo pose and T_end the pose where guidance converged::

    eye-in-hand  (the part moved by P P0^-1 = T_end T_start^-1, in base):  T_end T_start^-1 T_install
    eye-to-hand  (the grasp changed by G0 G^-1 = T_start^-1 T_end, in tool): T_install T_start^-1 T_end
    dual:        T_end1 T_start1^-1 T_install T_start2^-1 T_end2

The hand-eye transform appears only in the guidance step, not in the docking formulas: a hand-eye
error slows the loop's convergence, it does not bias the final correction (that is the point of
iterating). Tests in tests/guidance check every formula against a simulated cell.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.transforms import as_transform, inv, log_so3

F64 = NDArray[np.float64]


def delta_eye_in_hand(T_match: F64, T_tcp_cam: F64) -> F64:
    """Tool-frame step: ``T_base_tcp_new = T_base_tcp @ delta``."""
    T_match = as_transform(T_match, name="T_match")
    T_tcp_cam = as_transform(T_tcp_cam, name="T_tcp_cam")
    return T_tcp_cam @ inv(T_match) @ inv(T_tcp_cam)


def delta_eye_to_hand(T_match: F64, T_base_cam: F64) -> F64:
    """Base-frame step: ``T_base_tcp_new = delta @ T_base_tcp``."""
    T_match = as_transform(T_match, name="T_match")
    T_base_cam = as_transform(T_base_cam, name="T_base_cam")
    return T_base_cam @ T_match @ inv(T_base_cam)


def dock_eye_in_hand(T_start: F64, T_end: F64, T_install: F64) -> F64:
    """Corrected install pose when the incoming part moved (left-multiply, base frame)."""
    return (
        as_transform(T_end, name="T_end")
        @ inv(as_transform(T_start, name="T_start"))
        @ as_transform(T_install, name="T_install")
    )


def dock_eye_to_hand(T_start: F64, T_end: F64, T_install: F64) -> F64:
    """Corrected install pose when the grasp changed (right-multiply, tool frame)."""
    return (
        as_transform(T_install, name="T_install")
        @ inv(as_transform(T_start, name="T_start"))
        @ as_transform(T_end, name="T_end")
    )


def dock_dual(T_start1: F64, T_end1: F64, T_install: F64, T_start2: F64, T_end2: F64) -> F64:
    """Both corrections: incoming part (eye-in-hand stage 1) and grasp (eye-to-hand stage 2)."""
    return dock_eye_to_hand(T_start2, T_end2, dock_eye_in_hand(T_start1, T_end1, T_install))


def size_of(T: F64) -> tuple[float, float]:
    """(translation m, rotation rad) of a rigid transform."""
    T = np.asarray(T, dtype=float)
    return float(np.linalg.norm(T[:3, 3])), float(np.linalg.norm(log_so3(T[:3, :3])))


def converged(T_match: F64, translation_m: float, rotation_rad: float) -> bool:
    """True when the residual match is under both thresholds (seed 000: 0.1 mm / 0.01 deg)."""
    t, r = size_of(T_match)
    return t < translation_m and r < rotation_rad


def correction_between(T_from: F64, T_to: F64) -> tuple[float, float]:
    """How far a correction moves the TCP: (translation m, rotation rad) of ``T_from^-1 T_to``."""
    return size_of(inv(np.asarray(T_from, dtype=float)) @ np.asarray(T_to, dtype=float))


def over_limit(T_from: F64, T_to: F64, max_mm: float, max_deg: float, what: str) -> str | None:
    """Why the motion T_from -> T_to breaks the limit (a sentence naming *what*), or None if within."""
    t, r = correction_between(T_from, T_to)
    if t * 1e3 > max_mm or np.degrees(r) > max_deg:
        return f"{what} {t * 1e3:.2f} mm / {np.degrees(r):.2f} deg exceeds the limit {max_mm} mm / {max_deg} deg"
    return None


def not_converged_hint(residual_mm: list[float], residual_deg: list[float], tol: Any) -> str:
    """Why the loop did not converge, from its residuals per look and *tol* (``translation_tol_mm``,
    ``rotation_tol_deg``): residuals that stopped shrinking within 3x the tolerance mean the
    tolerance is below what one look resolves (the matcher's noise); anything else, that each move
    does not take the part where the view says, as a wrong hand-eye transform does."""
    last_mm, last_deg = residual_mm[-1], residual_deg[-1]
    near = last_mm < 3 * tol.translation_tol_mm and last_deg < 3 * tol.rotation_tol_deg
    stalled = len(residual_mm) >= 3 and last_mm > 0.5 * residual_mm[-3] and last_deg > 0.5 * residual_deg[-3]
    if near and stalled:
        return (
            f"the residuals stopped shrinking near the tolerance {tol.translation_tol_mm:g} mm / "
            f"{tol.rotation_tol_deg:g} deg: it is below what one look resolves; raise translation_tol_mm / "
            "rotation_tol_deg"
        )
    return "each move missed where the view said: check the hand-eye calibration"
