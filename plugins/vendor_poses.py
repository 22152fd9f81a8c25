"""Robot vendors' pose 6-vectors to and from vgr's 4x4 transforms, each by an explicitly named function.

An adapter or a file reader never guesses a vendor's convention: UR ``[x, y, z, rx, ry, rz]`` (m,
rotation vector), ABB ``trans`` in mm + ``rot`` quaternion ``(w, x, y, z)``, KUKA ``X Y Z A B C``
(mm, degrees, ``R = Rz(A) Ry(B) Rx(C)``). The engine knows nothing of robots; these live beside
the adapters (``plugins/devices/stages/ur_robot.py``) and the readers of robot pose files.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_pose7, T_from_rotvec, T_from_Rt, log_so3, pose7_from_T

F64 = NDArray[np.float64]


def T_from_ur(pose: Sequence[float]) -> F64:
    """UR pose ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad) -> T_base_tcp."""
    p = np.asarray(pose, dtype=float).reshape(6)
    return T_from_rotvec(p[3:], p[:3])


def ur_from_T(T: ArrayLike) -> F64:
    """T_base_tcp -> UR pose ``[x, y, z, rx, ry, rz]`` (m, rad)."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[:3, 3], log_so3(T[:3, :3])])


def T_from_abb(pos_mm: Sequence[float], quat_wxyz: Sequence[float]) -> F64:
    """ABB robtarget ``trans`` (mm) and ``rot`` quaternion (q1..q4 = w, x, y, z) -> 4x4 in metres."""
    w, x, y, z = np.asarray(quat_wxyz, dtype=float).reshape(4)
    return T_from_pose7(np.asarray(pos_mm, dtype=float) / 1000.0, (x, y, z, w))


def abb_from_T(T: ArrayLike) -> tuple[F64, F64]:
    """4x4 (m) -> ABB ``trans`` (mm) and ``rot`` (w, x, y, z) with w >= 0."""
    p, q = pose7_from_T(T)
    return p * 1000.0, np.array([q[3], q[0], q[1], q[2]])


def T_from_kuka_abc(xyzabc: Sequence[float]) -> F64:
    """KUKA ``X Y Z A B C`` (mm, degrees; R = Rz(A) Ry(B) Rx(C)) -> 4x4 in metres."""
    x, y, z, a, b, c = np.asarray(xyzabc, dtype=float).reshape(6)
    R = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()
    return T_from_Rt(R, np.array([x, y, z]) / 1000.0)


def kuka_abc_from_T(T: ArrayLike) -> F64:
    """4x4 (m) -> KUKA ``X Y Z A B C`` (mm, degrees)."""
    T = np.asarray(T, dtype=float)
    a, b, c = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    return np.concatenate([T[:3, 3] * 1000.0, [a, b, c]])
