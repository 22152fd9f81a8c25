"""Kinematic measurement samples and their plain-file format (shared with the model-gap workflow).

CSV format, one row per robot pose, header required:

``q1_deg .. qN_deg``      commanded joint angles in degrees
``x_mm, y_mm, z_mm``      a tool point measured in an external frame (laser tracker, camera ...), mm
optional ``qx, qy, qz, qw``  measured orientation of the tool frame in that frame (full-pose data)
optional ``t_s``          time since warm-up start (s)
optional ``dir1 .. dirN`` approach direction per joint (+1 / -1)
optional ``temp_c``       temperature (deg C); optional ``payload_kg`` mass at the TCP (kg)
optional ``point``        the name of the measured point (several reflectors or markers on the tool,
                          each measured at the same poses: one tool point per name, :mod:`.points`)

JSON form (``read_json`` / ``write_json``), the same columns as named fields of one object per pose::

    {"format": "vgr.kinematic.samples/1",
     "samples": [{"q1_deg": 0.0, "q2_deg": -90.0, ..., "x_mm": 512.3, "y_mm": -80.1, "z_mm": 390.0},
                 ...]}

(a bare list of such objects is accepted too; a field missing in one pose is an error).
``read_samples`` picks the reader by the suffix (``.csv`` / ``.json``).

Inside the code everything is SI (rad, m). Loading checks for NaN, non-unit quaternions, duplicate
poses and unit mix-ups (positions that look like metres in the ``_mm`` columns, joint angles that look
like radians in the ``_deg`` columns) and reports them.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from engine.plain_data import read_document
from plugins.robot.effects.base import SampleContext

F64 = NDArray[np.float64]


@dataclass
class KinematicSamples:
    """Joint angles (N, n) rad, measured tool-point positions (N, 3) m, optional orientations and context."""

    q: F64
    positions: F64
    rotations: F64 | None = None  # (N, 3, 3) measured tool orientations, full-pose data only
    t_s: F64 | None = None
    direction: F64 | None = None
    temp_c: F64 | None = None
    payload_kg: F64 | None = None
    point: NDArray[np.str_] | None = None  # (N,) the name of the measured point (several per pose), or None
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.q = np.asarray(self.q, dtype=float)
        self.positions = np.asarray(self.positions, dtype=float)
        if self.q.ndim != 2 or self.q.shape[0] == 0:
            raise ValueError(f"q must be (N, n) joint angles with N >= 1, got shape {self.q.shape}")
        n = self.q.shape[0]
        if self.positions.shape != (n, 3):
            raise ValueError(f"positions must be ({n}, 3), got {self.positions.shape}")
        for name in ("q", "positions"):
            bad = ~np.all(np.isfinite(getattr(self, name).reshape(n, -1)), axis=1)
            if np.any(bad):
                raise ValueError(f"{name} contains NaN or infinity in samples {np.flatnonzero(bad)[:5].tolist()}")
        if self.rotations is not None:
            R = np.asarray(self.rotations, dtype=float)
            if R.shape != (n, 3, 3):
                raise ValueError(f"rotations must be ({n}, 3, 3), got {R.shape}")
            if not np.all(np.isfinite(R)):
                raise ValueError("rotations contain NaN or infinity")
            err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
            det = np.linalg.det(R)
            bad = np.flatnonzero((err > 1e-6) | (np.abs(det - 1) > 1e-6))
            if bad.size:
                raise ValueError(
                    f"measured rotations are not orthonormal in samples {bad[:5].tolist()} "
                    f"(max |R R^T - I| = {err.max():.2e})"
                )
            self.rotations = R
        if self.point is not None:
            names = np.asarray(self.point).astype(str)
            if names.shape != (n,):
                raise ValueError(f"point must name the measured point of each of the {n} samples, got {names.shape}")
            empty = np.flatnonzero(np.char.strip(names) == "")
            if empty.size:
                raise ValueError(f"point is empty in samples {empty[:5].tolist()}: name every measured point")
            self.point = np.char.strip(names)
        # context is validated by SampleContext (broadcast, finite, +-1 directions)
        self.context().for_samples(n, self.q.shape[1])

    @property
    def n_samples(self) -> int:
        return self.q.shape[0]

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    @property
    def full_pose(self) -> bool:
        return self.rotations is not None

    @property
    def point_names(self) -> tuple[str, ...]:
        """The measured points' names in order of first appearance (``()`` without a ``point`` column)."""
        if self.point is None:
            return ()
        return tuple(dict.fromkeys(self.point.tolist()))

    def context(self) -> SampleContext:
        return SampleContext(self.t_s, self.direction, self.temp_c, self.payload_kg)

    def subset(self, idx: ArrayLike) -> KinematicSamples:
        idx = np.asarray(idx)

        def pick(a):
            return None if a is None else np.asarray(a)[idx]

        return KinematicSamples(
            self.q[idx],
            self.positions[idx],
            pick(self.rotations),
            pick(self.t_s),
            pick(self.direction),
            pick(self.temp_c),
            pick(self.payload_kg),
            pick(self.point),
        )

    def check(self) -> list[str]:
        """Warnings a user should see: duplicate poses, suspicious units, too few samples."""
        out = list(self.warnings)
        key = np.round(self.q, 9)
        if self.point is not None:  # several points measured at one pose are not duplicates
            key = np.column_stack([key, np.unique(self.point, return_inverse=True)[1]])
        _, counts = np.unique(key, axis=0, return_counts=True)
        dup = int(np.sum(counts[counts > 1] - 1))
        if dup:
            out.append(f"{dup} duplicate joint configurations: they add no excitation, only noise averaging")
        span = np.ptp(self.positions, axis=0).max() if self.n_samples > 1 else 0.0
        if span > 20.0:
            out.append(f"measured positions span {span:.0f} m: they look like millimetres given as metres")
        return out


_Q_COL = re.compile(r"^q(\d+)_deg$")
_DIR_COL = re.compile(r"^dir(\d+)$")


JSON_FORMAT = "vgr.kinematic.samples/1"


def read_csv(path: str | Path) -> KinematicSamples:
    """Read the CSV format of the module docstring (raises ValueError naming the problem)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path} does not exist")
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        header = reader.fieldnames or []
        rows = list(reader)
    return _from_rows(path, list(header), rows)


def read_json(path: str | Path) -> KinematicSamples:
    """Read the JSON form of the module docstring (the CSV columns as fields of one object per pose)."""
    path = Path(path)
    doc = read_document(path, "json", "kinematic samples file")
    if isinstance(doc, dict):
        fmt = doc.get("format", JSON_FORMAT)
        if fmt != JSON_FORMAT:
            raise ValueError(f"{path}: format {fmt!r} is not {JSON_FORMAT!r}")
        rows = doc.get("samples")
    else:
        rows = doc
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise ValueError(
            f"{path}: expected {{'format': {JSON_FORMAT!r}, 'samples': [{{...}}, ...]}} (one object per pose)"
        )
    header: list[str] = []
    for r in rows:
        header += [k for k in r if k not in header]
    missing = [(i, c) for i, r in enumerate(rows) for c in header if c not in r]
    if missing:
        i, c = missing[0]
        raise ValueError(f"{path}: pose {i} has no field {c!r} ({len(missing)} missing field(s) in all)")
    return _from_rows(path, header, rows)


def read_samples(path: str | Path) -> KinematicSamples:
    """``read_json`` for ``.json`` files, ``read_csv`` otherwise."""
    return read_json(path) if Path(path).suffix.lower() == ".json" else read_csv(path)


def _from_rows(path: Path, header: list[str], rows: list[dict]) -> KinematicSamples:
    """Samples from records keyed by the CSV column names (values: numbers or numeric strings)."""
    if not rows:
        raise ValueError(f"{path}: no data rows")
    q_cols = sorted((int(m.group(1)), c) for c in header if (m := _Q_COL.match(c)))
    if not q_cols or [i for i, _ in q_cols] != list(range(1, len(q_cols) + 1)):
        raise ValueError(f"{path}: need columns q1_deg .. qN_deg, got {header}")
    for c in ("x_mm", "y_mm", "z_mm"):
        if c not in header:
            raise ValueError(f"{path}: missing column {c!r}")

    def col(name: str) -> F64:
        try:
            return np.array([float(r[name]) if r[name] not in ("", None) else np.nan for r in rows])
        except (TypeError, ValueError) as e:
            raise ValueError(f"{path}: column {name!r}: {e}") from None

    q_deg = np.column_stack([col(c) for _, c in q_cols])
    pos_mm = np.column_stack([col(c) for c in ("x_mm", "y_mm", "z_mm")])
    warnings = []
    if np.abs(q_deg).max() <= 2 * np.pi and np.ptp(q_deg) > 0:
        warnings.append("all joint angles are within +-6.3: they look like radians in the *_deg columns")
    finite_pos = pos_mm[np.isfinite(pos_mm)]
    if finite_pos.size and np.abs(finite_pos).max() < 5.0:
        raise ValueError(
            f"{path}: positions in x_mm/y_mm/z_mm are all below 5 (max {np.abs(finite_pos).max():.3f}): "
            "they look like metres; the columns must be millimetres"
        )
    rotations = None
    if all(c in header for c in ("qx", "qy", "qz", "qw")):
        quat = np.column_stack([col(c) for c in ("qx", "qy", "qz", "qw")])
        norms = np.linalg.norm(quat, axis=1)
        if not np.all(np.isfinite(quat)) or np.any(np.abs(norms - 1) > 1e-3):
            raise ValueError(f"{path}: quaternions (qx, qy, qz, qw) must be finite and of unit norm")
        rotations = Rotation.from_quat(quat / norms[:, None]).as_matrix()
    dir_cols = sorted((int(m.group(1)), c) for c in header if (m := _DIR_COL.match(c)))
    direction = None
    if dir_cols:
        if [i for i, _ in dir_cols] != list(range(1, len(q_cols) + 1)):
            raise ValueError(f"{path}: need dir1 .. dir{len(q_cols)} together, got {[c for _, c in dir_cols]}")
        direction = np.column_stack([col(c) for _, c in dir_cols])
    point = None
    if "point" in header:
        point = np.array([str(r["point"] if r["point"] is not None else "").strip() for r in rows])
        blank = np.flatnonzero(point == "")
        if blank.size:
            raise ValueError(f"{path}: column 'point' is empty in row(s) {(blank[:5] + 1).tolist()}: name each point")
    samples = KinematicSamples(
        np.radians(q_deg),
        pos_mm / 1000.0,
        rotations,
        col("t_s") if "t_s" in header else None,
        direction,
        col("temp_c") if "temp_c" in header else None,
        col("payload_kg") if "payload_kg" in header else None,
        point,
    )
    samples.warnings = warnings
    return samples


def write_json(samples: KinematicSamples, path: str | Path) -> None:
    """Write samples in the JSON form of the module docstring (degrees, millimetres)."""
    header, data = _table(samples)
    rows = [dict(zip(header, map(float, row), strict=True)) for row in data]
    if samples.point is not None:
        for r, name in zip(rows, samples.point.tolist(), strict=True):
            r["point"] = name
    doc = {"format": JSON_FORMAT, "samples": rows}
    Path(path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def write_csv(samples: KinematicSamples, path: str | Path) -> None:
    """Write samples in the CSV format of the module docstring (degrees, millimetres)."""
    header, data = _table(samples)
    names = [] if samples.point is None else samples.point.tolist()
    with Path(path).open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header + (["point"] if names else []))
        for i, row in enumerate(data):
            w.writerow([repr(float(v)) for v in row] + ([names[i]] if names else []))


def _table(samples: KinematicSamples) -> tuple[list[str], F64]:
    """Column names and values (degrees, millimetres) of the plain formats."""
    n = samples.n_joints
    header = [f"q{j + 1}_deg" for j in range(n)] + ["x_mm", "y_mm", "z_mm"]
    cols = [np.degrees(samples.q), samples.positions * 1000.0]
    if samples.rotations is not None:
        header += ["qx", "qy", "qz", "qw"]
        cols.append(Rotation.from_matrix(samples.rotations).as_quat())
    for name in ("t_s", "temp_c", "payload_kg"):
        v = getattr(samples, name)
        if v is not None:
            header.append(name)
            cols.append(np.broadcast_to(v, (samples.n_samples,))[:, None])
    if samples.direction is not None:
        header += [f"dir{j + 1}" for j in range(n)]
        cols.append(np.broadcast_to(samples.direction, (samples.n_samples, n)))
    return header, np.column_stack(cols)
