"""Loading hand-eye samples (robot pose + camera observation pairs) from plain JSON and CSV files.

Formats (details and examples in docs/handeye.md):

* JSON, MoveIt calibration style: a list of ``[T_base_tcp, T_cam_target]`` pairs of 4x4 nested
  lists (MoveIt's ``eef_wrt_world`` and ``obj_wrt_sensor``).
* JSON, vgr style: ``{"format": "vgr.handeye.samples/1", "length_unit": "m", "setup": ...,
  "samples": [{"id": ..., "T_base_tcp": POSE, "T_cam_target": POSE}, ...]}`` where POSE is a 4x4
  nested list, ``{"position": [x, y, z], "quat_xyzw": [x, y, z, w]}`` or
  ``{"position": [...], "rotvec": [rx, ry, rz]}`` (rad).
* CSV with a header: ``base_tcp_x, base_tcp_y, base_tcp_z`` and either
  ``base_tcp_qx, base_tcp_qy, base_tcp_qz, base_tcp_qw`` or ``base_tcp_rx, base_tcp_ry, base_tcp_rz``
  (rotation vector, rad); the same with the prefix ``cam_target_``; optional ``id``. Lines starting
  with ``#`` are comments.

``length_unit`` is ``"m"`` or ``"mm"``; translations are converted to metres. Quaternions must be
unit within 1e-3 (else the columns are probably mixed up); rotation vectors longer than 2 pi are
degrees, not radians (error).
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.transforms import T_from_pose7, T_from_rotvec
from plugins.solvers.handeye.validation import HandEyeInputError

F64 = NDArray[np.float64]
VGR_FORMAT = "vgr.handeye.samples/1"
_UNITS = {"m": 1.0, "mm": 1e-3}

__all__ = [
    "VGR_FORMAT",
    "PoseSamples",
    "load_pose_pairs",
    "load_pose_pairs_csv",
    "load_pose_pairs_json",
    "write_pose_pairs_json",
]


@dataclass
class PoseSamples:
    """Loaded samples in metres: robot poses T_base_tcp and camera observations T_cam_target."""

    T_base_tcp: F64
    T_cam_target: F64
    ids: list[str] = field(default_factory=list)
    setup: str | None = None
    source: str = ""


def _scale(unit: str | None) -> float:
    if unit is None:
        return 1.0
    if unit not in _UNITS:
        raise HandEyeInputError(f"length_unit must be one of {list(_UNITS)}, got {unit!r}")
    return _UNITS[unit]


def _pose(position: Any, quat: Any = None, rotvec: Any = None, *, where: str) -> F64:
    p = np.asarray(position, dtype=float).reshape(3)
    if quat is not None:
        q = np.asarray(quat, dtype=float).reshape(4)
        norm = float(np.linalg.norm(q))
        if not np.isfinite(norm) or abs(norm - 1.0) > 1e-3:
            raise HandEyeInputError(
                f"{where}: quaternion {q} has norm {norm:.6g}, not 1 (column order x, y, z, w mixed up?)"
            )
        return T_from_pose7(p, q)
    r = np.asarray(rotvec, dtype=float).reshape(3)
    if np.linalg.norm(r) > 2.0 * np.pi + 1e-9:
        raise HandEyeInputError(f"{where}: rotation vector {r} is longer than 2 pi: degrees instead of radians?")
    return T_from_rotvec(r, p)


def _pose_from_json(obj: Any, where: str) -> F64:
    if isinstance(obj, dict):
        if "position" not in obj:
            raise HandEyeInputError(f"{where}: pose object needs 'position' and 'quat_xyzw' or 'rotvec'")
        if "quat_xyzw" in obj:
            return _pose(obj["position"], quat=obj["quat_xyzw"], where=where)
        if "rotvec" in obj:
            return _pose(obj["position"], rotvec=obj["rotvec"], where=where)
        raise HandEyeInputError(f"{where}: pose object needs 'quat_xyzw' or 'rotvec'")
    A = np.asarray(obj, dtype=float)
    if A.shape != (4, 4):
        raise HandEyeInputError(f"{where}: expected a 4x4 matrix, got shape {A.shape}")
    return A


def _in_metres(
    path: Path, M: list[F64], B: list[F64], ids: list[str], setup: str | None, length_unit: str | None
) -> PoseSamples:
    """The loaded poses as samples, translations converted from *length_unit* to metres."""
    if not M:
        raise HandEyeInputError(f"{path}: no samples")
    s = _scale(length_unit)
    Ma, Ba = np.array(M), np.array(B)
    Ma[:, :3, 3] *= s
    Ba[:, :3, 3] *= s
    return PoseSamples(Ma, Ba, ids, setup, str(path))


def load_pose_pairs_json(path: str | Path, *, length_unit: str | None = None) -> PoseSamples:
    """Load the MoveIt list-of-pairs JSON or the vgr samples JSON (see module docstring)."""
    path = Path(path)
    data = json.loads(path.read_text())
    setup = None
    ids: list[str] = []
    if isinstance(data, dict):
        if data.get("format") != VGR_FORMAT:
            raise HandEyeInputError(f"{path}: unknown JSON format {data.get('format')!r}; expected {VGR_FORMAT!r}")
        file_unit = data.get("length_unit", "m")
        if length_unit is not None and length_unit != file_unit:
            raise HandEyeInputError(f"{path}: file says length_unit={file_unit!r} but {length_unit!r} was asked")
        length_unit = file_unit
        setup = data.get("setup")
        samples = data.get("samples", [])
        M = [_pose_from_json(s["T_base_tcp"], f"{path} sample {k} T_base_tcp") for k, s in enumerate(samples)]
        B = [_pose_from_json(s["T_cam_target"], f"{path} sample {k} T_cam_target") for k, s in enumerate(samples)]
        ids = [str(s.get("id", k)) for k, s in enumerate(samples)]
    elif isinstance(data, list):
        M, B = [], []
        for k, pair in enumerate(data):
            if not isinstance(pair, list) or len(pair) != 2:
                raise HandEyeInputError(f"{path}: entry {k} is not a [T_base_tcp, T_cam_target] pair")
            M.append(_pose_from_json(pair[0], f"{path} entry {k} T_base_tcp"))
            B.append(_pose_from_json(pair[1], f"{path} entry {k} T_cam_target"))
        ids = [str(k) for k in range(len(M))]
    else:
        raise HandEyeInputError(f"{path}: JSON must be a list of pose pairs or a {VGR_FORMAT} object")
    return _in_metres(path, M, B, ids, setup, length_unit)


def _csv_pose(row: dict[str, str], prefix: str, where: str) -> F64:
    def get(name: str) -> float:
        try:
            return float(row[prefix + name])
        except ValueError as exc:
            raise HandEyeInputError(f"{where}: column {prefix + name} is not a number ({exc})") from exc

    pos = [get("x"), get("y"), get("z")]
    if prefix + "qw" in row:
        return _pose(pos, quat=[get("qx"), get("qy"), get("qz"), get("qw")], where=where)
    return _pose(pos, rotvec=[get("rx"), get("ry"), get("rz")], where=where)


def load_pose_pairs_csv(path: str | Path, *, length_unit: str = "m") -> PoseSamples:
    """Load the CSV format of the module docstring."""
    path = Path(path)
    with path.open(newline="") as fh:
        lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    reader = csv.DictReader(lines, skipinitialspace=True)
    cols = set(reader.fieldnames or [])
    for prefix in ("base_tcp_", "cam_target_"):
        pos = {prefix + c for c in ("x", "y", "z")}
        quat = {prefix + c for c in ("qx", "qy", "qz", "qw")}
        rvec = {prefix + c for c in ("rx", "ry", "rz")}
        if not pos <= cols or not (quat <= cols or rvec <= cols):
            raise HandEyeInputError(
                f"{path}: missing columns for {prefix}*: need {sorted(pos)} and either {sorted(quat)} or {sorted(rvec)}"
            )
    M, B, ids = [], [], []
    for k, row in enumerate(reader):
        where = f"{path} row {k + 1}"
        M.append(_csv_pose(row, "base_tcp_", where))
        B.append(_csv_pose(row, "cam_target_", where))
        ids.append(row.get("id") or str(k))
    return _in_metres(path, M, B, ids, None, length_unit)


def load_pose_pairs(path: str | Path, *, length_unit: str | None = None) -> PoseSamples:
    """Load samples from ``.json`` or ``.csv`` (by suffix)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".json":
        return load_pose_pairs_json(path, length_unit=length_unit)
    if suffix == ".csv":
        return load_pose_pairs_csv(path, length_unit=length_unit or "m")
    raise HandEyeInputError(f"{path}: unsupported file type {suffix!r} (use .json or .csv)")


def write_pose_pairs_json(
    path: str | Path,
    T_base_tcp: F64,
    T_cam_target: F64,
    *,
    ids: list[str] | None = None,
    setup: str | None = None,
) -> None:
    """Write samples (metres) in the vgr JSON format, poses as 4x4 nested lists."""
    n = len(T_base_tcp)
    ids = ids or [str(k) for k in range(n)]
    doc: dict[str, Any] = {"format": VGR_FORMAT, "length_unit": "m"}
    if setup is not None:
        doc["setup"] = setup
    doc["samples"] = [
        {
            "id": ids[k],
            "T_base_tcp": np.asarray(T_base_tcp[k]).tolist(),
            "T_cam_target": np.asarray(T_cam_target[k]).tolist(),
        }
        for k in range(n)
    ]
    Path(path).write_text(json.dumps(doc, indent=1))
