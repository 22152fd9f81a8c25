"""Plain-file formats of Vive desk contact data (JSON and CSV), documented in docs/vive_and_tcp.md.

JSON (``"format": "vgr.vive_desk/1"``)::

    {"format": "vgr.vive_desk/1", "units": "m",            # "m" or "mm": positions, offsets, sigmas
     "contact_offset_z": 0.12,                              # TCP height above each contact point
     "fixture_quat_xyzw": [0, 0, 0, 1],                     # nominal R_desktop_tcp (default identity)
     "noise": {"tracker_position_sigma": 0.0005, "tracker_rotation_sigma_deg": 0.1,
               "fixture_rotation_sigma_deg": 0.3, "desk_point_sigma": 0.0},
     "contacts": [{"label": "P1", "desk_point": [0, 0, 0],
                   "tracker_position": [x, y, z], "tracker_quat_xyzw": [qx, qy, qz, qw],
                   "fixture_quat_xyzw": [...] or "free",     # optional, per contact
                   "tcp_offset": [0, 0, 0.12]}]}              # optional, per contact (desk frame)

``"T_base_tracker": 4x4`` may replace position + quaternion. CSV: ``# key = value`` metadata lines
(the same keys as the JSON top level; quaternions as 4 comma-separated numbers), then a header row
with ``desk_x, desk_y, desk_z, tracker_x, tracker_y, tracker_z, tracker_qx, tracker_qy, tracker_qz,
tracker_qw`` and optionally ``label``, ``orientation`` (``fixed``/``free``), ``fixture_qx..qw``,
``offset_x, offset_y, offset_z``. Quaternions are (x, y, z, w); they must be unit within 1e-3.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from engine.transforms import pose7_from_T
from plugins.calibration.sample_files import (
    length_scale,
    pose_entries,
    quat_matrix,
    read_csv_samples,
    read_json_samples,
    row_numbers,
    sample_pose,
    write_csv_samples,
    written_metadata,
)
from plugins.calibration.vive_desk.data import ViveDeskData, ViveNoiseModel

FORMAT = "vgr.vive_desk/1"
_CSV_REQUIRED = [
    "desk_x", "desk_y", "desk_z", "tracker_x", "tracker_y", "tracker_z",
    "tracker_qx", "tracker_qy", "tracker_qz", "tracker_qw",
]  # fmt: skip


def _noise(meta: dict[str, Any], k: float) -> ViveNoiseModel:
    base = ViveNoiseModel()
    return ViveNoiseModel(
        tracker_position_sigma_m=float(meta.get("tracker_position_sigma", base.tracker_position_sigma_m / k)) * k,
        tracker_rotation_sigma_rad=float(
            np.radians(float(meta.get("tracker_rotation_sigma_deg", np.degrees(base.tracker_rotation_sigma_rad))))
        ),
        fixture_rotation_sigma_rad=float(
            np.radians(float(meta.get("fixture_rotation_sigma_deg", np.degrees(base.fixture_rotation_sigma_rad))))
        ),
        desk_point_sigma_m=float(meta.get("desk_point_sigma", 0.0)) * k,
    )


def _build(meta: dict[str, Any], rows: list[dict[str, Any]]) -> ViveDeskData:
    k = length_scale(str(meta.get("units", "m")))
    if not rows:
        raise ValueError("no contacts in the file")
    R_default = quat_matrix(meta.get("fixture_quat_xyzw", [0, 0, 0, 1]), "fixture_quat_xyzw")
    off_z = float(meta.get("contact_offset_z", 0.12 / k)) * k
    P, T, R, off, known, labels = [], [], [], [], [], []
    for i, c in enumerate(rows):
        where = f"contact {i + 1}"
        labels.append(str(c.get("label") or f"P{i + 1}"))
        P.append(np.asarray(c["desk_point"], dtype=float) * k)
        T.append(sample_pose(c, "tracker", k, where))
        fq = c.get("fixture_quat_xyzw")
        known.append(fq != "free")
        R.append(R_default if fq in (None, "free") else quat_matrix(fq, f"{where} fixture_quat_xyzw"))
        off.append(np.asarray(c.get("tcp_offset", [0.0, 0.0, off_z / k]), dtype=float) * k)
    return ViveDeskData.from_contacts(
        np.array(P),
        np.array(T),
        tcp_offsets_desktop=np.array(off),
        R_desktop_tcp=np.array(R),
        orientation_known=np.array(known),
        noise=_noise(meta, k),
        labels=labels,
    )


def load_vive_json(path: str | Path) -> ViveDeskData:
    """Read a ``vgr.vive_desk/1`` JSON file (see module docstring)."""
    return _build(*read_json_samples(path, FORMAT, "contacts"))


def load_vive_csv(path: str | Path) -> ViveDeskData:
    """Read the CSV variant (``# key = value`` metadata, then a header row; see module docstring)."""
    meta, header, csv_rows = read_csv_samples(path)
    missing = [c for c in _CSV_REQUIRED if c not in header]
    if missing:
        raise ValueError(f"{path}: CSV header lacks columns {missing}")
    rows = []
    for n, r in enumerate(csv_rows):
        c: dict[str, Any] = {
            "label": r.get("label", ""),
            "desk_point": row_numbers(path, n, r, ["desk_x", "desk_y", "desk_z"]),
            "tracker_position": row_numbers(path, n, r, ["tracker_x", "tracker_y", "tracker_z"]),
            "tracker_quat_xyzw": row_numbers(path, n, r, ["tracker_qx", "tracker_qy", "tracker_qz", "tracker_qw"]),
        }
        if r.get("orientation", "fixed").lower() == "free":
            c["fixture_quat_xyzw"] = "free"
        elif r.get("fixture_qw"):
            c["fixture_quat_xyzw"] = row_numbers(path, n, r, ["fixture_qx", "fixture_qy", "fixture_qz", "fixture_qw"])
        if r.get("offset_x"):
            c["tcp_offset"] = row_numbers(path, n, r, ["offset_x", "offset_y", "offset_z"])
        rows.append(c)
    return _build(meta, rows)


def _metadata(data: ViveDeskData) -> dict[str, Any]:
    nz = data.noise
    noise = {
        "tracker_position_sigma": nz.tracker_position_sigma_m,
        "tracker_rotation_sigma_deg": float(np.degrees(nz.tracker_rotation_sigma_rad)),
        "fixture_rotation_sigma_deg": float(np.degrees(nz.fixture_rotation_sigma_rad)),
        "desk_point_sigma": nz.desk_point_sigma_m,
    }
    return written_metadata(FORMAT, noise)


def vive_to_json_dict(data: ViveDeskData) -> dict[str, Any]:
    """The JSON document of *data* (metres), the inverse of :func:`load_vive_json`."""
    contacts = []
    for i in range(data.n):
        c: dict[str, Any] = {
            "label": data.labels[i],
            "desk_point": data.desk_points[i].tolist(),
            **pose_entries(data.T_base_tracker[i], "tracker"),
            "tcp_offset": data.tcp_offsets_desktop[i].tolist(),
        }
        if data.orientation_known[i]:
            c["fixture_quat_xyzw"] = Rotation.from_matrix(data.R_desktop_tcp[i]).as_quat().tolist()
        else:
            c["fixture_quat_xyzw"] = "free"
        contacts.append(c)
    return {**_metadata(data), "contacts": contacts}


def save_vive_json(data: ViveDeskData, path: str | Path) -> None:
    Path(path).write_text(json.dumps(vive_to_json_dict(data), indent=2))


def save_vive_csv(data: ViveDeskData, path: str | Path) -> None:
    """Write the CSV variant (metres, per-contact fixture orientation and offset columns)."""
    cols = ["label", *_CSV_REQUIRED, "orientation", "fixture_qx", "fixture_qy", "fixture_qz", "fixture_qw"]
    cols += ["offset_x", "offset_y", "offset_z"]
    rows = []
    for i in range(data.n):
        p, q = pose7_from_T(data.T_base_tracker[i])
        fq = Rotation.from_matrix(data.R_desktop_tcp[i]).as_quat()
        orient = "fixed" if data.orientation_known[i] else "free"
        num = [*data.desk_points[i], *p, *q]
        extra = [*fq, *data.tcp_offsets_desktop[i]]
        rows.append([data.labels[i], *(repr(float(v)) for v in num), orient, *(repr(float(v)) for v in extra)])
    write_csv_samples(path, _metadata(data), cols, rows)
