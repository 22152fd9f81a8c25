"""Robot flange poses ``T_base_tcp`` for hand-eye from images: reading the pose file.

Formats, told apart by their content (the suffix only picks JSON):

* **4x4 rows** (``RobotPosesVec.txt`` of RWHE-Calib and many lab tools): one row of 16 numbers per
  image, the 4x4 matrix row-major, translations in metres.
* **UR pose CSV**: one row of 6 numbers per image, ``x, y, z, rx, ry, rz`` (metres, rotation vector
  in radians: the UR pendant's notation), an optional header row (any row that is not numbers).
* **vgr JSON**: ``{"length_unit": "m", "poses": [POSE, ...]}`` or a plain list of POSE, where POSE
  is a 4x4 nested list, ``{"position": [x, y, z], "quat_xyzw": [...]}`` or ``{"position": [...],
  "rotvec": [...]}``; a ``vgr.handeye.samples/1`` file is read for its ``T_base_tcp`` entries.

Separators: white space, commas or semicolons; ``#`` starts a comment. ``length_unit="mm"`` (or
``"length_unit": "mm"`` in JSON) converts millimetres. Every pose is checked (finite, a rotation
within 1e-3, last row ``0 0 0 1``); a bad one raises :class:`RobotPoseFileError` naming the line.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.transforms import T_from_pose7, T_from_rotvec

F64 = NDArray[np.float64]

__all__ = ["RobotPoseFileError", "load_robot_poses"]

_UNITS = {"m": 1.0, "mm": 1e-3}
_SPLIT = re.compile(r"[\s,;]+")
ROT_TOL = 1e-3


class RobotPoseFileError(ValueError):
    """A robot pose file that cannot be read; the message names the file and the line."""


def _check(T: F64, where: str) -> F64:
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise RobotPoseFileError(f"{where}: not a finite 4x4 pose")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise RobotPoseFileError(f"{where}: last row {T[3].tolist()} is not 0 0 0 1 (column-major matrix?)")
    R = T[:3, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROT_TOL or np.linalg.det(R) < 0:
        raise RobotPoseFileError(f"{where}: the 3x3 block is not a rotation (wrong layout, or not a pose file?)")
    return T


def _scale(unit: str | None, where: str) -> float:
    if unit is None:
        return 1.0
    if unit not in _UNITS:
        raise RobotPoseFileError(f"{where}: length unit {unit!r} unknown (use m or mm)")
    return _UNITS[unit]


def _text_rows(text: str, where: str) -> list[tuple[int, list[float]]]:
    rows: list[tuple[int, list[float]]] = []
    for k, line in enumerate(text.splitlines(), start=1):
        body = line.split("#", 1)[0].strip()
        if not body:
            continue
        fields = [f for f in _SPLIT.split(body) if f]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if not rows:  # a header row
                continue
            raise RobotPoseFileError(f"{where}:{k}: not numbers: {body[:60]!r}") from None
        rows.append((k, values))
    return rows


def _from_text(text: str, where: str, scale: float) -> F64:
    rows = _text_rows(text, where)
    if not rows:
        raise RobotPoseFileError(f"{where}: no poses in the file")
    poses: list[F64] = []
    for k, v in rows:
        if len(v) == 16:
            T = np.asarray(v, float).reshape(4, 4)
        elif len(v) == 6:
            T = T_from_rotvec(v[3:], v[:3])
        else:
            raise RobotPoseFileError(
                f"{where}:{k}: {len(v)} numbers; a row is a 4x4 pose (16 numbers, row-major) or a UR pose "
                "(6 numbers: x y z rx ry rz)"
            )
        if len(v) != len(rows[0][1]):
            raise RobotPoseFileError(f"{where}:{k}: {len(v)} numbers where the first row has {len(rows[0][1])}")
        T = _check(np.array(T, dtype=float), f"{where}:{k}")
        T[:3, 3] *= scale
        poses.append(T)
    return np.stack(poses)


def _json_pose(obj: Any, where: str) -> F64:
    if isinstance(obj, dict):
        if "position" not in obj:
            raise RobotPoseFileError(f"{where}: a pose needs 'position' and 'quat_xyzw' or 'rotvec'")
        try:
            if "quat_xyzw" in obj:
                q = np.asarray(obj["quat_xyzw"], float)
                if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > 1e-3:
                    raise RobotPoseFileError(f"{where}: quat_xyzw must be a unit quaternion of 4 numbers")
                return np.asarray(T_from_pose7(obj["position"], q), float)
            if "rotvec" in obj:
                return np.asarray(T_from_rotvec(obj["rotvec"], obj["position"]), float)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, RobotPoseFileError):
                raise
            raise RobotPoseFileError(f"{where}: {exc}") from None
        raise RobotPoseFileError(f"{where}: a pose needs 'quat_xyzw' or 'rotvec' beside 'position'")
    try:
        return np.asarray(obj, dtype=float)
    except (TypeError, ValueError):
        raise RobotPoseFileError(f"{where}: not a 4x4 pose") from None


def _from_json(text: str, where: str, unit: str | None) -> F64:
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RobotPoseFileError(f"{where}: not JSON ({exc})") from None
    if isinstance(doc, dict):
        unit = doc.get("length_unit", unit)
        if "poses" in doc:
            items = doc["poses"]
        elif "samples" in doc and isinstance(doc["samples"], list):
            items = [s.get("T_base_tcp") if isinstance(s, dict) else None for s in doc["samples"]]
        else:
            raise RobotPoseFileError(f"{where}: expected 'poses' (or 'samples' with T_base_tcp)")
    else:
        items = doc
    if not isinstance(items, list) or not items:
        raise RobotPoseFileError(f"{where}: no poses in the file")
    scale = _scale(unit if isinstance(unit, str) or unit is None else str(unit), where)
    out = []
    for i, item in enumerate(items):
        T = _check(_json_pose(item, f"{where}: pose {i}"), f"{where}: pose {i}")
        T = T.copy()
        T[:3, 3] *= scale
        out.append(T)
    return np.stack(out)


def load_robot_poses(path: str | Path, *, length_unit: str | None = None) -> F64:
    """``T_base_tcp`` ``(n, 4, 4)`` in metres from a pose file (formats in the module docstring)."""
    p = Path(path)
    where = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RobotPoseFileError(f"{where}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RobotPoseFileError(f"{where}: cannot read it as text ({exc})") from None
    if p.suffix.lower() == ".json":
        return _from_json(text, where, length_unit)
    return _from_text(text, where, _scale(length_unit, where))
