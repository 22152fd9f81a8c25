"""Plain-file formats of TCP-by-camera data (JSON and CSV), documented in docs/vive_and_tcp.md.

JSON (``"format": "vgr.tcp_camera/1"``)::

    {"format": "vgr.tcp_camera/1",
     "units": "m", "camera_units": "m",          # robot positions / camera points: "m" or "mm"
     "noise": {"camera_sigma": 0.0003,           # or [sx, sy, sz] (camera axes), camera_units
               "robot_position_sigma": 0.0,      # units
               "robot_rotation_sigma_deg": 0.0},
     "samples": [{"label": "S1",
                  "flange_position": [x, y, z], "flange_quat_xyzw": [qx, qy, qz, qw],
                  "p_cam": [x, y, z]}]}

A sample may give ``"T_base_flange": 4x4`` or ``"ur_pose": [x, y, z, rx, ry, rz]`` (UR rotation
vector) instead of position + quaternion. CSV: ``# key = value`` metadata lines (the JSON top-level
and noise keys), then a header with ``cam_x, cam_y, cam_z`` and either
``flange_x, flange_y, flange_z, flange_qx, flange_qy, flange_qz, flange_qw`` or
``flange_x, flange_y, flange_z, flange_rx, flange_ry, flange_rz`` (UR), optional ``label``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from engine.transforms import pose7_from_T
from plugins.calibration.sample_files import (
    length_scale,
    pose_entries,
    read_csv_samples,
    read_json_samples,
    row_numbers,
    sample_pose,
    write_csv_samples,
    written_metadata,
)
from plugins.calibration.tcp_camera.data import TcpCameraData, TcpNoiseModel
from plugins.vendor_poses import T_from_ur

FORMAT = "vgr.tcp_camera/1"
_CSV_QUAT_HEADER = [
    "flange_x", "flange_y", "flange_z", "flange_qx", "flange_qy", "flange_qz", "flange_qw",
    "cam_x", "cam_y", "cam_z",
]  # fmt: skip


def _build(meta: dict[str, Any], samples: list[dict[str, Any]]) -> TcpCameraData:
    k_r = length_scale(meta.get("units", "m"))
    k_c = length_scale(meta.get("camera_units", "m"), "camera_units")
    if not samples:
        raise ValueError("no samples in the file")
    T, P, labels = [], [], []
    for i, s in enumerate(samples):
        where = f"sample {i + 1}"
        labels.append(str(s.get("label") or f"S{i + 1}"))
        if "ur_pose" in s and "T_base_flange" not in s:  # UR pose 6-vector (a 4x4 T_base_flange wins)
            u = np.asarray(s["ur_pose"], dtype=float).reshape(6)
            T.append(T_from_ur(np.concatenate([u[:3] * k_r, u[3:]])))
        else:
            T.append(sample_pose(s, "flange", k_r, where))
        P.append(np.asarray(s["p_cam"], dtype=float) * k_c)
    cam_sigma = np.broadcast_to(np.asarray(meta.get("camera_sigma", 0.3e-3 / k_c), dtype=float), (3,)) * k_c
    noise = TcpNoiseModel(
        tuple(float(v) for v in cam_sigma),
        float(meta.get("robot_position_sigma", 0.0)) * k_r,
        float(np.radians(float(meta.get("robot_rotation_sigma_deg", 0.0)))),
    )
    return TcpCameraData.from_arrays(np.array(T), np.array(P), noise=noise, labels=labels)


def load_tcp_json(path: str | Path) -> TcpCameraData:
    return _build(*read_json_samples(path, FORMAT, "samples"))


def load_tcp_csv(path: str | Path) -> TcpCameraData:
    meta, header, rows = read_csv_samples(path)
    need = ["flange_x", "flange_y", "flange_z", "cam_x", "cam_y", "cam_z"]
    quat_cols = ["flange_qx", "flange_qy", "flange_qz", "flange_qw"]
    ur_cols = ["flange_rx", "flange_ry", "flange_rz"]
    missing = [c for c in need if c not in header]
    if missing or not (all(c in header for c in quat_cols) or all(c in header for c in ur_cols)):
        raise ValueError(f"{path}: CSV header needs {need} and either {quat_cols} or {ur_cols}; missing {missing}")
    use_quat = all(c in header for c in quat_cols)
    samples = []
    for n, r in enumerate(rows):
        pos = row_numbers(path, n, r, ("flange_x", "flange_y", "flange_z"))
        s: dict[str, Any] = {"label": r.get("label", ""), "p_cam": row_numbers(path, n, r, ("cam_x", "cam_y", "cam_z"))}
        if use_quat:
            s["flange_position"] = pos
            s["flange_quat_xyzw"] = row_numbers(path, n, r, quat_cols)
        else:
            s["ur_pose"] = pos + row_numbers(path, n, r, ur_cols)
        samples.append(s)
    return _build(meta, samples)


def _metadata(data: TcpCameraData) -> dict[str, Any]:
    nz = data.noise
    noise = {
        "camera_sigma": list(nz.camera_sigma_m),
        "robot_position_sigma": nz.robot_position_sigma_m,
        "robot_rotation_sigma_deg": float(np.degrees(nz.robot_rotation_sigma_rad)),
    }
    return written_metadata(FORMAT, noise, camera_units="m")


def tcp_to_json_dict(data: TcpCameraData) -> dict[str, Any]:
    samples = []
    for i in range(data.n):
        samples.append(
            {"label": data.labels[i], **pose_entries(data.T_base_flange[i], "flange"), "p_cam": data.p_cam[i].tolist()}
        )
    return {**_metadata(data), "samples": samples}


def save_tcp_json(data: TcpCameraData, path: str | Path) -> None:
    Path(path).write_text(json.dumps(tcp_to_json_dict(data), indent=2))


def save_tcp_csv(data: TcpCameraData, path: str | Path) -> None:
    rows = []
    for i in range(data.n):
        p, q = pose7_from_T(data.T_base_flange[i])
        rows.append([data.labels[i], *(repr(float(v)) for v in (*p, *q, *data.p_cam[i]))])
    write_csv_samples(path, _metadata(data), ["label", *_CSV_QUAT_HEADER], rows)
