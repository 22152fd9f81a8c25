"""What the plain-file sample formats of the TCP-by-camera and Vive desk calibrations share.

Both formats (docs/vive_and_tcp.md) are a JSON document ``{"format": ..., <metadata>, "noise":
{...}, <list of samples>}`` or a CSV file of ``# key = value`` metadata lines (the JSON top-level and
noise keys; several comma-separated numbers make a list) followed by a header row and one row per
sample. This module owns reading and writing that frame: the length units (``"m"`` / ``"mm"``),
quaternion columns (x, y, z, w; unit within 1e-3), a sample's pose (``T_base_<name>`` 4x4 or
``<name>_position`` + ``<name>_quat_xyzw``), the metadata and the numbered data rows; the
calibration packages own their keys and columns.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, pose7_from_T

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}


def length_scale(units: Any, key: str = "units") -> float:
    """Metres per unit of *units* (``"m"`` or ``"mm"``); ValueError naming the metadata *key* otherwise."""
    if units not in LENGTH_UNITS:
        raise ValueError(f"{key} must be 'm' or 'mm', got {units!r}")
    return LENGTH_UNITS[units]


def quat_matrix(q: ArrayLike, where: str) -> NDArray[np.float64]:
    """Rotation matrix of the quaternion (x, y, z, w) *q*, which must be unit within 1e-3."""
    q = np.asarray(q, dtype=float).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"{where}: quaternion must be 4 finite numbers (x, y, z, w), got {q.tolist()}")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise ValueError(f"{where}: quaternion norm is {n:.4f}, not 1 (wrong columns or order?)")
    return Rotation.from_quat(q / n).as_matrix()


def sample_pose(sample: Mapping[str, Any], name: str, scale: float, where: str) -> NDArray[np.float64]:
    """The pose ``T_base_<name>`` of one sample: the 4x4 under that key, else ``<name>_position`` and
    ``<name>_quat_xyzw``; positions times *scale* (metres per file unit)."""
    key = f"T_base_{name}"
    if key in sample:
        T = np.array(sample[key], dtype=float)
        if T.shape != (4, 4):
            raise ValueError(f"{where}: {key} must be 4x4")
        T[:3, 3] *= scale
        return T
    R = quat_matrix(sample[f"{name}_quat_xyzw"], f"{where} {name}_quat_xyzw")
    return T_from_Rt(R, np.asarray(sample[f"{name}_position"], dtype=float) * scale)


def pose_entries(T: ArrayLike, name: str) -> dict[str, list[float]]:
    """``<name>_position`` (metres) and ``<name>_quat_xyzw`` of the 4x4 *T*: how a written file gives a
    sample's pose, read back by :func:`sample_pose`."""
    p, q = pose7_from_T(T)
    return {f"{name}_position": p.tolist(), f"{name}_quat_xyzw": q.tolist()}


def read_json_samples(path: str | Path, fmt: str, list_key: str) -> tuple[dict[str, Any], list[Any]]:
    """(metadata, samples) of a JSON document of format *fmt* (a missing ``format`` is accepted): the
    metadata are the top-level keys with those of ``noise`` merged in, the samples are ``list_key``."""
    d = json.loads(Path(path).read_text())
    if d.get("format", fmt) != fmt:
        raise ValueError(f"{path}: format {d.get('format')!r} is not {fmt!r}")
    return {**d, **d.get("noise", {})}, list(d.get(list_key, []))


def written_metadata(fmt: str, noise: Mapping[str, Any], **keys: Any) -> dict[str, Any]:
    """The metadata of a sample file vgr writes: format *fmt*, lengths in metres (``units``), the
    other top-level *keys*, then ``noise``."""
    return {"format": fmt, "units": "m", **keys, "noise": dict(noise)}


def _metadata_value(text: str) -> Any:
    parts = [p.strip() for p in text.split(",")]
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        return text.strip()
    return nums if len(nums) > 1 else nums[0]


def read_csv_samples(path: str | Path) -> tuple[dict[str, Any], list[str], list[dict[str, str]]]:
    """(metadata, header, rows) of a CSV sample file; cells and column names are stripped of spaces."""
    meta: dict[str, Any] = {}
    body: list[str] = []
    for line in Path(path).read_text().splitlines():
        s = line.strip()
        if s.startswith("#"):
            if "=" in s:
                key, val = s[1:].split("=", 1)
                meta[key.strip()] = _metadata_value(val)
        elif s:
            body.append(line)
    reader = csv.DictReader(io.StringIO("\n".join(body)))
    header = [h.strip() for h in reader.fieldnames or []]
    rows = [{k.strip(): (v or "").strip() for k, v in raw.items() if k is not None} for raw in reader]
    return meta, header, rows


def row_numbers(path: str | Path, n: int, row: Mapping[str, str], cols: Sequence[str]) -> list[float]:
    """The numbers in columns *cols* of data row *n* (0-based) of *path*; ValueError naming the row."""
    try:
        return [float(row[c]) for c in cols]
    except ValueError as exc:
        raise ValueError(f"{path}: data row {n + 1}: {exc}") from exc


def write_csv_samples(
    path: str | Path, metadata: Mapping[str, Any], header: Sequence[str], rows: Iterable[Sequence[Any]]
) -> None:
    """Write a CSV sample file that :func:`read_csv_samples` reads back: *metadata* (the JSON top-level
    keys, ``noise`` flattened into them) as ``# key = value`` lines (numbers exactly, lists of numbers
    comma-separated, strings as they are), then the header and the rows."""
    out = io.StringIO()
    for key, v in {**{k: v for k, v in metadata.items() if k != "noise"}, **metadata.get("noise", {})}.items():
        if isinstance(v, str):
            text = v
        elif isinstance(v, Sequence | np.ndarray):
            text = ", ".join(repr(float(x)) for x in v)
        else:
            text = repr(float(v))
        out.write(f"# {key} = {text}\n")
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    Path(path).write_text(out.getvalue())
