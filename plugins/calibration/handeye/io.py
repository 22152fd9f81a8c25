"""Loading hand-eye samples (robot pose + camera observation pairs) from JSON, CSV and OpenCV YAML files.

Formats (details and examples in docs/handeye.md):

* JSON, MoveIt calibration style: a list of ``[T_base_tcp, T_cam_target]`` pairs of 4x4 nested
  lists (MoveIt's ``eef_wrt_world`` and ``obj_wrt_sensor``). Sample ids: the list index, from 0.
* JSON, vgr style: ``{"format": "vgr.handeye.samples/1", "length_unit": "m", "setup": ...,
  "samples": [{"id": ..., "T_base_tcp": POSE, "T_cam_target": POSE}, ...]}`` where POSE is a 4x4
  nested list, ``{"position": [x, y, z], "quat_xyzw": [x, y, z, w]}`` or
  ``{"position": [...], "rotvec": [rx, ry, rz]}`` (rad). Sample ids: ``id`` (else the index).
* CSV with a header: ``base_tcp_x, base_tcp_y, base_tcp_z`` and either
  ``base_tcp_qx, base_tcp_qy, base_tcp_qz, base_tcp_qw`` or ``base_tcp_rx, base_tcp_ry, base_tcp_rz``
  (rotation vector, rad); the same with the prefix ``cam_target_``; optional ``id``. Lines starting
  with ``#`` are comments. Sample ids: the ``id`` column, else ``line N`` (the line in the file).
* JSON, two stamped streams (``vgr.handeye.streams/1``): robot and camera poses each with its own
  stamp, paired by interpolation with the clock offset estimated: read by
  plugins/calibration/handeye/stream_file.py (``load_samples`` reads that and every format here).
* OpenCV FileStorage YAML in camodocal's ``TransformPairsInput.yml`` layout (the ROS wrapper
  handeye_calib_camodocal writes and reads it): ``%YAML:1.0``, ``frameCount: N`` and, per sample
  ``i``, ``T1_i`` (robot base -> end effector, ``T_base_tcp``) and ``T2_i`` (camera -> marker,
  ``T_cam_target``), each a 4x4 ``!!opencv-matrix`` in metres (row-major ``data``). Read with
  OpenCV's own parser (``cv2.FileStorage``). Sample ids: ``i``.

A sample whose robot or camera pose is missing (every number of it NaN, or, in CSV, every cell of
it empty: a view where the target was not detected) is dropped, and named in
``PoseSamples.dropped``; a pose with only some numbers missing, or an infinity, is an error, as
other impossible values are.

``length_unit`` is ``"m"`` or ``"mm"``; translations are converted to metres. Quaternions must be
unit within 1e-3 (else the columns are probably mixed up); rotation vectors longer than 2 pi are
degrees, not radians (error).

Per-sample camera covariances (optional, ``PoseSamples.camera_covariances``, what
``calibrate_hand_eye(..., camera_covariances=)`` takes): in the vgr JSON a sample's ``camera_cov``
(36 numbers, the 6x6 covariance of the decoupled ``(dt, dphi)`` camera-frame perturbation ordered
``(tx, ty, tz, rx, ry, rz)``, row-major; length unit^2, rad^2, length unit x rad) or ``camera_sigma``
(6 numbers: length unit and rad, a diagonal covariance); in CSV the columns ``camera_cov_RC`` (R, C
= 0..5) or ``camera_sigma_tx`` .. ``camera_sigma_rz``; in OpenCV YAML ``camera_cov_<i>`` (6x6
``!!opencv-matrix``) or ``camera_sigma_<i>`` (6 values) beside ``T1_<i>`` / ``T2_<i>``. Every sample
or none; converted to metres with the poses; bad ones refused naming the sample
(plugins/calibration/handeye/covariance_file.py). MoveIt's list of pairs has none.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.transforms import T_from_pose7, T_from_rotvec
from plugins.calibration.handeye.covariance_file import (
    covariance_entry,
    covariance_from_csv,
    covariances_in_metres,
    csv_covariance_kind,
    json_covariance,
)
from plugins.calibration.handeye.validation import HandEyeInputError

F64 = NDArray[np.float64]
VGR_FORMAT = "vgr.handeye.samples/1"
STREAMS_FORMAT = "vgr.handeye.streams/1"  # two stamped streams: plugins/calibration/handeye/stream_file.py
_UNITS = {"m": 1.0, "mm": 1e-3}

__all__ = [
    "VGR_FORMAT",
    "PoseSamples",
    "load_pose_pairs",
    "load_pose_pairs_csv",
    "load_pose_pairs_json",
    "load_pose_pairs_yaml",
    "write_pose_pairs_json",
    "write_pose_pairs_yaml",
]


@dataclass
class PoseSamples:
    """Loaded samples in metres: robot poses T_base_tcp and camera observations T_cam_target, with
    the id the file gives each sample (``ids``, what reports name samples by) and its set-up, if any."""

    T_base_tcp: F64
    T_cam_target: F64
    ids: list[str] = field(default_factory=list)
    setup: str | None = None
    source: str = ""
    dropped: list[str] = field(default_factory=list)  # samples left out: "<id> (<which pose> missing)"
    notes: list[str] = field(default_factory=list)  # what the loading did (a stream file's clock offset)
    metrics: dict[str, float] = field(default_factory=dict)  # what the loading measured (clock_offset_s, ...)
    # (n, 6, 6) each sample's camera covariance in metres and radians (module docstring), or None
    camera_covariances: F64 | None = None


def unit_scale(unit: str | None) -> float:
    if unit is None:
        return 1.0
    if unit not in _UNITS:
        raise HandEyeInputError(f"length_unit must be one of {list(_UNITS)}, got {unit!r}")
    return _UNITS[unit]


MISSING = np.full((4, 4), np.nan)  # a pose the file does not have (e.g. no detection in that view)


def _pose(position: Any, quat: Any = None, rotvec: Any = None, *, where: str) -> F64:
    p = np.asarray(position, dtype=float).reshape(3)
    rot = np.asarray(quat if quat is not None else rotvec, dtype=float)
    if np.isnan(p).all() and np.isnan(rot).all():
        return MISSING
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


def pose_from_json(obj: Any, where: str) -> F64:
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
    path: Path,
    M: list[F64],
    B: list[F64],
    ids: list[str],
    setup: str | None,
    length_unit: str | None,
    covs: list[F64 | None] | None = None,
) -> PoseSamples:
    """The loaded poses as samples, translations (and the camera covariances *covs*, one per sample
    or None) converted from *length_unit* to metres."""
    if not M:
        raise HandEyeInputError(f"{path}: no samples")
    s = unit_scale(length_unit)
    Ma, Ba = np.array(M), np.array(B)
    # missing: every number of the pose's top three rows NaN (a part-NaN pose is refused by the checks)
    robot_ok = ~np.isnan(Ma[:, :3, :]).all(axis=(1, 2))
    camera_ok = ~np.isnan(Ba[:, :3, :]).all(axis=(1, 2))
    dropped = []
    for k, (robot, camera) in enumerate(zip(robot_ok, camera_ok, strict=True)):
        if not (robot and camera):
            which = " and ".join(w for w, ok in (("robot pose", robot), ("camera pose", camera)) if not ok)
            dropped.append(f"{ids[k]} ({which} missing)")
    keep = robot_ok & camera_ok
    if not keep.any():
        raise HandEyeInputError(f"{path}: no sample has both poses ({len(ids)} samples, every one with a pose missing)")
    Ma, Ba = Ma[keep], Ba[keep]
    Ma[:, :3, 3] *= s
    Ba[:, :3, 3] *= s
    kept = [i for i, k in zip(ids, keep, strict=True) if k]
    kept_covs = None if covs is None else [covs[k] for k in np.flatnonzero(keep)]
    cov = None if kept_covs is None else covariances_in_metres(kept_covs, kept, s, path)
    return PoseSamples(Ma, Ba, kept, setup, str(path), dropped, camera_covariances=cov)


def load_pose_pairs_json(path: str | Path, *, length_unit: str | None = None) -> PoseSamples:
    """Load the MoveIt list-of-pairs JSON or the vgr samples JSON (see module docstring)."""
    path = Path(path)
    data = json.loads(path.read_text())
    setup = None
    ids: list[str] = []
    covs: list[F64 | None] | None = None
    if isinstance(data, dict):
        if data.get("format") == STREAMS_FORMAT:
            raise HandEyeInputError(
                f"{path}: {STREAMS_FORMAT} holds two streams, not samples: "
                "read it with plugins.calibration.handeye.stream_file.load_samples"
            )
        if data.get("format") != VGR_FORMAT:
            raise HandEyeInputError(f"{path}: unknown JSON format {data.get('format')!r}; expected {VGR_FORMAT!r}")
        file_unit = data.get("length_unit", "m")
        if length_unit is not None and length_unit != file_unit:
            raise HandEyeInputError(f"{path}: file says length_unit={file_unit!r} but {length_unit!r} was asked")
        length_unit = file_unit
        setup = data.get("setup")
        samples = data.get("samples", [])
        M = [pose_from_json(s["T_base_tcp"], f"{path} sample {k} T_base_tcp") for k, s in enumerate(samples)]
        B = [pose_from_json(s["T_cam_target"], f"{path} sample {k} T_cam_target") for k, s in enumerate(samples)]
        ids = [str(s.get("id", k)) for k, s in enumerate(samples)]
        covs = [
            covariance_entry(s.get("camera_cov"), s.get("camera_sigma"), f"{path} sample {i}")
            for i, s in zip(ids, samples, strict=True)
        ]
    elif isinstance(data, list):
        M, B = [], []
        for k, pair in enumerate(data):
            if not isinstance(pair, list) or len(pair) != 2:
                raise HandEyeInputError(f"{path}: entry {k} is not a [T_base_tcp, T_cam_target] pair")
            M.append(pose_from_json(pair[0], f"{path} entry {k} T_base_tcp"))
            B.append(pose_from_json(pair[1], f"{path} entry {k} T_cam_target"))
        ids = [str(k) for k in range(len(M))]
    else:
        raise HandEyeInputError(f"{path}: JSON must be a list of pose pairs or a {VGR_FORMAT} object")
    return _in_metres(path, M, B, ids, setup, length_unit, covs)


def _csv_pose(row: dict[str, str], prefix: str, where: str) -> F64:
    def get(name: str) -> float:
        cell = (row[prefix + name] or "").strip()
        if not cell:  # an empty cell: the pose is missing
            return float("nan")
        try:
            return float(cell)
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
        numbered = [(k + 1, ln) for k, ln in enumerate(fh) if ln.strip() and not ln.lstrip().startswith("#")]
    line_of = [k for k, _ in numbered[1:]]  # file line of each data row (the first kept line is the header)
    reader = csv.DictReader([ln for _, ln in numbered], skipinitialspace=True)
    cols = set(reader.fieldnames or [])
    for prefix in ("base_tcp_", "cam_target_"):
        pos = {prefix + c for c in ("x", "y", "z")}
        quat = {prefix + c for c in ("qx", "qy", "qz", "qw")}
        rvec = {prefix + c for c in ("rx", "ry", "rz")}
        if not pos <= cols or not (quat <= cols or rvec <= cols):
            raise HandEyeInputError(
                f"{path}: missing columns for {prefix}*: need {sorted(pos)} and either {sorted(quat)} or {sorted(rvec)}"
            )
    kind = csv_covariance_kind(cols, path)
    M, B, ids, covs = [], [], [], []
    for k, row in enumerate(reader):
        line = f"line {line_of[k]}" if k < len(line_of) else f"row {k + 1}"
        where = f"{path} {line}"
        M.append(_csv_pose(row, "base_tcp_", where))
        B.append(_csv_pose(row, "cam_target_", where))
        ids.append((row.get("id") or "").strip() or line)
        covs.append(covariance_from_csv(row, kind, f"{path} sample {ids[-1]}"))
    return _in_metres(path, M, B, ids, None, length_unit, covs)


_PAIR_KEY = re.compile(r"^T([12])_(.+)$")
YAML_SUFFIXES = (".yml", ".yaml")


def _file_storage_root(path: Path) -> Any:
    """The root node of an OpenCV FileStorage YAML file, with errors a user can act on."""
    head = path.read_bytes()[:64]
    if not head.lstrip().startswith(b"%YAML"):
        raise HandEyeInputError(
            f"{path}: not an OpenCV FileStorage YAML file (it must start with %YAML:1.0, as camodocal's "
            "TransformPairsInput.yml does)"
        )
    import cv2  # heavy: only when a YAML file is read

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the parser reports malformed YAML as either
        cause = exc.__cause__ or exc
        detail = str(cause).strip().splitlines()[-1] if str(cause).strip() else type(cause).__name__
        raise HandEyeInputError(f"{path}: OpenCV cannot parse this YAML ({detail})") from None
    if not fs.isOpened():
        raise HandEyeInputError(f"{path}: OpenCV cannot open this YAML file")
    return fs


def _yaml_matrix(fs: Any, key: str, path: Path, shape: tuple[int, int] | None = (4, 4)) -> F64:
    """The ``!!opencv-matrix`` at *key*, of *shape* (None: any)."""
    import cv2

    node = fs.getNode(key)
    try:
        mat = node.mat() if node.isMap() else None
    except cv2.error as exc:
        raise HandEyeInputError(f"{path}: {key} is a malformed opencv-matrix ({str(exc).strip()[-120:]})") from None
    if mat is None:
        raise HandEyeInputError(f"{path}: {key} is not an opencv-matrix (a 4x4 !!opencv-matrix is expected)")
    A = np.asarray(mat, dtype=float)
    if shape is None:
        return A
    if A.shape != (4, 4):
        raise HandEyeInputError(f"{path}: {key} is {A.shape[0]}x{A.shape[1] if A.ndim > 1 else 1}, not 4x4")
    return A


def load_pose_pairs_yaml(path: str | Path, *, length_unit: str | None = None) -> PoseSamples:
    """Load OpenCV FileStorage YAML pose pairs in camodocal's ``TransformPairsInput.yml`` layout.

    ``T1_i`` is the robot pose ``T_base_tcp`` and ``T2_i`` the camera's marker pose ``T_cam_target``
    of sample ``i`` (its id); ``frameCount``, when present, must equal the number of pairs. Samples
    are ordered by ``i`` when every id is an integer, else as in the file.
    """
    path = Path(path)
    fs = _file_storage_root(path)
    try:
        root = fs.root()
        keys: list[str] = list(root.keys()) if root.isMap() else []
        pairs: dict[str, dict[str, str]] = {}
        for key in keys:
            m = _PAIR_KEY.match(key)
            if m:
                pairs.setdefault(m.group(2), {})[m.group(1)] = key
        if not pairs:
            raise HandEyeInputError(
                f"{path}: no T1_<i> / T2_<i> matrices (camodocal's TransformPairsInput.yml layout: T1_i the robot "
                f"pose base -> end effector, T2_i the camera -> marker pose); keys found: {keys[:8] or 'none'}"
            )
        for i, got in pairs.items():
            if set(got) != {"1", "2"}:
                have, miss = ("T1", "T2") if "1" in got else ("T2", "T1")
                raise HandEyeInputError(f"{path}: {have}_{i} has no {miss}_{i}: every sample needs both poses")
        if "frameCount" in keys:
            node = fs.getNode("frameCount")
            count = node.real() if node.isInt() or node.isReal() else None
            if count is None or count != len(pairs):
                said = "is not a number" if count is None else f"says {count:g}"
                raise HandEyeInputError(f"{path}: frameCount {said} but the file holds {len(pairs)} T1_/T2_ pairs")
        ids = list(pairs)
        if all(re.fullmatch(r"\d+", i) for i in ids):
            ids.sort(key=int)
        M = [_yaml_matrix(fs, pairs[i]["1"], path) for i in ids]
        B = [_yaml_matrix(fs, pairs[i]["2"], path) for i in ids]
        covs = [_yaml_covariance(fs, keys, i, path) for i in ids]
    finally:
        fs.release()
    return _in_metres(path, M, B, ids, None, length_unit or "m", covs)


def _yaml_covariance(fs: Any, keys: list[str], i: str, path: Path) -> F64 | None:
    """Sample *i*'s ``camera_cov_<i>`` / ``camera_sigma_<i>`` matrix as a covariance, or None."""
    got = {k: _yaml_matrix(fs, f"{k}_{i}", path, None) for k in ("camera_cov", "camera_sigma") if f"{k}_{i}" in keys}
    return covariance_entry(got.get("camera_cov"), got.get("camera_sigma"), f"{path} sample {i}")


def write_pose_pairs_yaml(
    path: str | Path, T_base_tcp: F64, T_cam_target: F64, *, camera_covariances: F64 | None = None
) -> None:
    """Write samples (metres) in camodocal's ``TransformPairsInput.yml`` layout (OpenCV FileStorage),
    with ``camera_cov_<i>`` when *camera_covariances* ``(n, 6, 6)`` are given."""
    import cv2

    n = len(T_base_tcp)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("frameCount", n)
        for k in range(n):
            fs.write(f"T1_{k}", np.asarray(T_base_tcp[k], dtype=float))
            fs.write(f"T2_{k}", np.asarray(T_cam_target[k], dtype=float))
            if camera_covariances is not None:
                fs.write(f"camera_cov_{k}", np.asarray(camera_covariances[k], dtype=float))
    finally:
        fs.release()


def load_pose_pairs(path: str | Path, *, length_unit: str | None = None) -> PoseSamples:
    """Load samples from ``.json``, ``.csv`` or OpenCV ``.yml`` / ``.yaml`` (by suffix)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".json":
        return load_pose_pairs_json(path, length_unit=length_unit)
    if suffix == ".csv":
        return load_pose_pairs_csv(path, length_unit=length_unit or "m")
    if suffix in YAML_SUFFIXES:
        return load_pose_pairs_yaml(path, length_unit=length_unit)
    raise HandEyeInputError(f"{path}: unsupported file type {suffix!r} (use .json, .csv or .yml)")


def write_pose_pairs_json(
    path: str | Path,
    T_base_tcp: F64,
    T_cam_target: F64,
    *,
    ids: list[str] | None = None,
    setup: str | None = None,
    camera_covariances: F64 | None = None,
) -> None:
    """Write samples (metres) in the vgr JSON format, poses as 4x4 nested lists, with ``camera_cov``
    when *camera_covariances* ``(n, 6, 6)`` are given."""
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
            **({} if camera_covariances is None else {"camera_cov": json_covariance(camera_covariances[k])}),
        }
        for k in range(n)
    ]
    Path(path).write_text(json.dumps(doc, indent=1))
