"""Model-gap input data: the kinematic CSV with its optional columns, and vgr recordings.

CSV columns (header required, one row per measurement; unknown columns are errors with a suggestion):

``q1_deg .. qN_deg``         commanded joint angles (deg)                                   required
``x_mm, y_mm, z_mm``         tool point measured in the external (sensor) frame (mm)        required
``t_s``                      time since warm-up start (s)          -> thermal_drift, time localisation
``dir1 .. dirN``             approach direction per joint (+1 / -1) -> backlash
``temp_c``                   temperature (deg C)                    -> localisation
``payload_kg``               mass at the TCP (kg)                   -> joint_compliance (gravity torque)
``qd1_deg_s .. qdN_deg_s``   joint velocities at the measurement (deg/s) -> time_latency
``range_mm``                 range measured by a sensor whose centre is the frame origin (mm)
                                                                    -> depth_scale, depth_bias
``sigma_mm``                 per-sample measurement noise, 1 sigma per axis (mm) (else --noise-mm)
``point``                    name of the measured point (several reflectors / markers per pose, each its
                             own row): one tool point per name, one frame and geometry for all
``qx, qy, qz, qw``           measured tool orientation: accepted, not used by the gap workflow yet

Recordings (MCAP written by ``vgr run``) are read by :mod:`.recordings`. Inside the code everything is SI.
"""

from __future__ import annotations

import csv
import difflib
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.calibration.kinematics import KinematicSamples, read_csv

F64 = NDArray[np.float64]

OPTIONAL_SCALARS = ("t_s", "temp_c", "payload_kg", "range_mm", "sigma_mm")
QUATERNION = ("qx", "qy", "qz", "qw")
_PATTERNS = {
    "q": re.compile(r"^q(\d+)_deg$"),
    "dir": re.compile(r"^dir(\d+)$"),
    "qd": re.compile(r"^qd(\d+)_deg_s$"),
}


# frames whose origin is not a measuring instrument's centre: no range is derived from points in them
NOT_SENSOR_FRAMES = frozenset({"", "world", "map", "odom", "base", "base_link", "robot", "tcp", "flange", "tool0"})


class GapDataError(ValueError):
    """The data cannot be used as given (the message says why and what to do)."""


@dataclass
class GapData:
    """Samples for the model-gap workflow (SI units): kinematic samples plus optional streams."""

    samples: KinematicSamples
    qd: F64 | None = None  # (N, n) rad/s
    range_m: F64 | None = None  # (N,) m
    sigma_m: F64 | None = None  # (N,) m, per axis
    sensor: str = "sensor"
    source: str = ""
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        n, dof = self.samples.n_samples, self.samples.n_joints
        if self.qd is not None:
            self.qd = np.asarray(self.qd, dtype=float)
            if self.qd.shape != (n, dof):
                raise GapDataError(f"joint velocities must be ({n}, {dof}), got {self.qd.shape}")
            _finite_rows(self.qd, "joint velocities")
        for name in ("range_m", "sigma_m"):
            v = getattr(self, name)
            if v is None:
                continue
            a = np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()
            _finite_rows(a, name)
            if np.any(a <= 0):
                raise GapDataError(f"{name} must be > 0 (samples {np.flatnonzero(a <= 0)[:5].tolist()})")
            setattr(self, name, a)

    @property
    def n_samples(self) -> int:
        return self.samples.n_samples

    @property
    def n_joints(self) -> int:
        return self.samples.n_joints

    @property
    def columns(self) -> set[str]:
        """Optional data present: ``t_s direction temp_c payload_kg qd range sigma``."""
        s = self.samples
        have = {
            "t_s": s.t_s is not None,
            "direction": s.direction is not None,
            "temp_c": s.temp_c is not None,
            "payload_kg": s.payload_kg is not None,
            "qd": self.qd is not None,
            "range": self.range_m is not None,
            "sigma": self.sigma_m is not None,
        }
        return {k for k, v in have.items() if v}

    def subset(self, idx: ArrayLike) -> GapData:
        idx = np.asarray(idx)
        return GapData(
            self.samples.subset(idx),
            None if self.qd is None else self.qd[idx],
            None if self.range_m is None else self.range_m[idx],
            None if self.sigma_m is None else self.sigma_m[idx],
            self.sensor,
            self.source,
            list(self.warnings),
        )


def _finite_rows(a: F64, name: str) -> None:
    bad = ~np.all(np.isfinite(a.reshape(a.shape[0], -1)), axis=1)
    if np.any(bad):
        raise GapDataError(f"{name} contain NaN or infinity in samples {np.flatnonzero(bad)[:5].tolist()}")


# --------------------------------------------------------------------------- CSV


def known_columns(n_joints: int) -> list[str]:
    """Every column name the CSV format accepts for a robot with ``n_joints`` joints."""
    cols = [f"q{j}_deg" for j in range(1, n_joints + 1)] + ["x_mm", "y_mm", "z_mm"]
    cols += list(OPTIONAL_SCALARS) + list(QUATERNION) + ["point"]
    cols += [f"dir{j}" for j in range(1, n_joints + 1)]
    cols += [f"qd{j}_deg_s" for j in range(1, n_joints + 1)]
    return cols


_ALIASES = {  # frequent spellings -> the format's name (checked before fuzzy matching)
    "x": "x_mm",
    "y": "y_mm",
    "z": "z_mm",
    "x_m": "x_mm",
    "y_m": "y_mm",
    "z_m": "z_mm",
    "t": "t_s",
    "time": "t_s",
    "time_s": "t_s",
    "temperature": "temp_c",
    "payload": "payload_kg",
    "range": "range_mm",
    "depth_mm": "range_mm",
    "sigma": "sigma_mm",
}


def suggest_column(name: str, n_joints: int) -> str | None:
    """The format's column a misspelt header most likely means (``x_m`` -> ``x_mm``, ``q1`` -> ``q1_deg``)."""
    low = name.strip().lower()
    if low in _ALIASES:
        return _ALIASES[low]
    m = re.match(r"^(?:q|j|joint|theta|a)_?(\d+)(?:_?(?:deg|rad|degrees))?$", low)
    if m:
        return f"q{m.group(1)}_deg"
    m = re.match(r"^(?:qd|dq|v|vel|qdot)_?(\d+)(?:_.*)?$", low)
    if m:
        return f"qd{m.group(1)}_deg_s"
    m = re.match(r"^(?:dir|direction|d)_?(\d+)$", low)
    if m:
        return f"dir{m.group(1)}"
    known = known_columns(max(n_joints, 1))
    if low in known:
        return low
    close = difflib.get_close_matches(low, known, n=1, cutoff=0.6)
    return close[0] if close else None


def _check_header(path: Path, header: list[str]) -> int:
    """Validate column names; return the number of joints. Raises GapDataError with suggestions."""
    q_idx = sorted(int(m.group(1)) for c in header if (m := _PATTERNS["q"].match(c)))
    n = len(q_idx)
    problems = []
    if not q_idx or q_idx != list(range(1, n + 1)):
        guess = [c for c in header if (s := suggest_column(c, 6)) and s.startswith("q") and "_deg_s" not in s]
        hint = f" (found {guess}: name them q1_deg, q2_deg, ...)" if guess else ""
        problems.append(f"joint columns must be q1_deg .. qN_deg without gaps{hint}")
    known = set(known_columns(max(n, 1)))
    for c in header:
        if c in known:
            continue
        s = suggest_column(c, max(n, 1))
        problems.append(f"unknown column {c!r}" + (f" (did you mean {s!r}?)" if s else ""))
    for c in ("x_mm", "y_mm", "z_mm"):
        if c not in header:
            s = [h for h in header if suggest_column(h, max(n, 1)) == c]
            problems.append(f"missing column {c!r}" + (f" (is it {s[0]!r}?)" if s else ""))
    for kind in ("dir", "qd"):
        idx = sorted(int(m.group(1)) for c in header if (m := _PATTERNS[kind].match(c)))
        if idx and idx != list(range(1, n + 1)):
            problems.append(f"{kind} columns must cover joints 1..{n} together, got joints {idx}")
    quat = [c for c in QUATERNION if c in header]
    if quat and len(quat) != 4:
        problems.append(f"orientation needs all of qx, qy, qz, qw; got {quat}")
    if problems:
        raise GapDataError(f"{path}: " + "; ".join(problems))
    return n


def read_gap_csv(path: str | Path, *, sensor: str = "sensor") -> GapData:
    """Read the CSV format of the module docstring. Raises :class:`GapDataError` naming the problem."""
    path = Path(path)
    if not path.is_file():
        raise GapDataError(f"{path} does not exist")
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        header = [h.strip() for h in (reader.fieldnames or [])]
        rows = list(reader)
    if not header:
        raise GapDataError(f"{path}: empty file (a header line is required)")
    if not rows:
        raise GapDataError(f"{path}: no data rows")
    n = _check_header(path, header)
    raw_header = reader.fieldnames or []

    def col(name: str) -> F64:
        key = raw_header[header.index(name)]
        vals = []
        for i, r in enumerate(rows):
            v = (r.get(key) or "").strip()
            try:
                vals.append(float(v) if v else np.nan)
            except ValueError:
                raise GapDataError(f"{path}: line {i + 2}, column {name!r}: {v!r} is not a number") from None
        a = np.array(vals)
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            lines = (bad[:5] + 2).tolist()
            raise GapDataError(f"{path}: column {name!r} is empty, NaN or infinite on line(s) {lines}")
        return a

    for c in header:  # NaN / text anywhere, named by column and line, before any other check
        if c != "point":  # the point's name is text
            col(c)
    try:
        samples = read_csv(path)
    except ValueError as e:
        raise GapDataError(str(e)) from None
    warnings = list(samples.warnings)
    if samples.rotations is not None:
        warnings.append("orientation columns (qx..qw) are read but not used: the gap workflow fits positions")
        samples.rotations = None
    qd = None
    if "qd1_deg_s" in header:
        qd = np.radians(np.column_stack([col(f"qd{j}_deg_s") for j in range(1, n + 1)]))
    range_m = None
    if "range_mm" in header:
        r = col("range_mm")
        if np.abs(r).max() < 5.0:
            raise GapDataError(f"{path}: range_mm values are all below 5 mm: they look like metres")
        range_m = r / 1000.0
        dist = np.linalg.norm(samples.positions, axis=1)
        mismatch = np.abs(dist - range_m) > 1e-3 + 1e-3 * range_m
        if np.any(mismatch):
            i = int(np.flatnonzero(mismatch)[0])
            raise GapDataError(
                f"{path}: range_mm disagrees with the distance of (x_mm, y_mm, z_mm) from the frame origin "
                f"(line {i + 2}: {range_m[i] * 1e3:.2f} vs {dist[i] * 1e3:.2f} mm): depth effects need the "
                "points in the ranging sensor's own frame (its centre at the origin)"
            )
    sigma = None
    if "sigma_mm" in header:
        s = col("sigma_mm")
        if np.any(s <= 0):
            raise GapDataError(f"{path}: sigma_mm must be > 0")
        if np.any(s > 1000):
            raise GapDataError(f"{path}: sigma_mm above 1 m: not a plausible measurement noise (units?)")
        sigma = s / 1000.0
    data = GapData(samples, qd, range_m, sigma, sensor=sensor, source=str(path), warnings=warnings)
    return data


def write_gap_csv(data: GapData, path: str | Path) -> Path:
    """Write ``data`` in the CSV format (degrees, millimetres; optional columns when present)."""
    s = data.samples
    n = s.n_joints
    header = [f"q{j + 1}_deg" for j in range(n)] + ["x_mm", "y_mm", "z_mm"]
    cols: list[F64] = [np.degrees(s.q), s.positions * 1e3]
    for name, v, scale in (
        ("t_s", s.t_s, 1.0),
        ("temp_c", s.temp_c, 1.0),
        ("payload_kg", s.payload_kg, 1.0),
        ("range_mm", data.range_m, 1e3),
        ("sigma_mm", data.sigma_m, 1e3),
    ):
        if v is not None:
            header.append(name)
            cols.append(np.broadcast_to(np.asarray(v) * scale, (s.n_samples,))[:, None])
    if s.direction is not None:
        header += [f"dir{j + 1}" for j in range(n)]
        cols.append(np.broadcast_to(s.direction, (s.n_samples, n)))
    if data.qd is not None:
        header += [f"qd{j + 1}_deg_s" for j in range(n)]
        cols.append(np.degrees(data.qd))
    table = np.column_stack(cols)
    names = [] if s.point is None else s.point.tolist()
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header + (["point"] if names else []))
        for i, row in enumerate(table):
            w.writerow([repr(float(v)) for v in row] + ([names[i]] if names else []))
    return path


def with_payload(data: GapData, payload_kg: float) -> GapData:
    """*data* with the same payload (kg at the TCP) at every sample; refuses to replace one it has."""
    if not (np.isfinite(payload_kg) and payload_kg >= 0):
        raise GapDataError(f"payload must be finite and >= 0 kg, got {payload_kg}")
    if data.samples.payload_kg is not None:
        raise GapDataError(f"{data.source or 'the data'} already has a payload per sample; not replacing it")
    data.samples = replace(data.samples, payload_kg=np.full(data.n_samples, float(payload_kg)))
    return data
