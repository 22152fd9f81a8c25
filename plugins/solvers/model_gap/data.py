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
``qx, qy, qz, qw``           measured tool orientation: accepted, not used by the gap workflow yet

Recordings (MCAP written by ``vgr run``): the joints come from a ``JointState`` topic (the robot's
``/<robot>/joint_state``), the measurements from a ``TrackerPose`` or ``PoseStamped`` topic (position
of the measured point in the sensor frame, metres), e.g. ``/tracker/pose``. Each measurement is paired
with the joint state interpolated at its stamp; the joint velocities come from the JointState (or its
finite differences), the approach direction from the sign of each joint's last motion, ``t_s`` from
the first joint state, the range (depth effects) from ``|p|`` when the measurements are in the
instrument's own frame (see :func:`pair_streams`). Inside the code everything is SI.
"""

from __future__ import annotations

import csv
import difflib
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plugins.solvers.kinematic_calibration import KinematicSamples, read_csv

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
    cols += list(OPTIONAL_SCALARS) + list(QUATERNION)
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
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in table:
            w.writerow([repr(float(v)) for v in row])
    return path


# --------------------------------------------------------------------------- recordings


def read_gap_mcap(
    path: str | Path,
    *,
    joint_topic: str | None = None,
    measurement_topic: str | None = None,
    max_interp_gap_s: float = 10.0,
    payload_kg: float | None = None,
) -> GapData:
    """Pair a recording's joint states with its measurements (see the module docstring). The payload
    is *payload_kg* if given, else the robot stage's ``payload_kg`` parameter in the recorded recipe."""
    from engine import codec
    from engine.recording import RecordingError, load

    try:
        rec = load(path)
    except RecordingError as e:
        raise GapDataError(str(e)) from None
    types = {t: meta.get("type", "") for t, meta in rec.channels.items()}
    joints = [t for t, ty in types.items() if ty == "JointState"]
    meas = [t for t, ty in types.items() if ty in ("TrackerPose", "PoseStamped") and "/truth/" not in t]
    if joint_topic is None and len(joints) > 1:  # prefer the joints published next to the measurements
        # (a measurement_campaign publishes both: the joints on arrival and the tracker reading)
        trackers = [t for t in meas if types[t] == "TrackerPose"]
        stage_of = {t: t.strip("/").split("/")[0] for t in joints + trackers}
        paired = [t for t in joints if any(stage_of[m] == stage_of[t] for m in trackers)]
        if len(paired) == 1:
            joint_topic = paired[0]
            if measurement_topic is None:
                same = [m for m in trackers if stage_of[m] == stage_of[joint_topic]]
                measurement_topic = same[0] if len(same) == 1 else None
    if joint_topic is None:
        if len(joints) != 1:
            raise GapDataError(f"{path}: {len(joints)} JointState topics {joints}: name one with --joint-topic")
        joint_topic = joints[0]
    elif joint_topic not in types:
        close = difflib.get_close_matches(joint_topic, list(types), n=1)
        raise GapDataError(f"{path}: no topic {joint_topic!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    robot_stage = joint_topic.strip("/").split("/")[0]
    if measurement_topic is None:  # a measurement from another stage than the joints' (a tracker, a camera)
        others = [t for t in meas if t.strip("/").split("/")[0] != robot_stage]
        if len(others) != 1:
            raise GapDataError(
                f"{path}: cannot tell the measurement topic among {others or meas}: name it with --measurement-topic"
            )
        measurement_topic = others[0]
    elif measurement_topic not in types:
        close = difflib.get_close_matches(measurement_topic, list(types), n=1)
        raise GapDataError(
            f"{path}: no topic {measurement_topic!r}" + (f" (did you mean {close[0]!r}?)" if close else "")
        )
    if types[measurement_topic] not in ("TrackerPose", "PoseStamped"):
        raise GapDataError(f"{measurement_topic} carries {types[measurement_topic]}, not a TrackerPose/PoseStamped")
    jcls, mcls = codec.registry.get("JointState"), codec.registry.get(types[measurement_topic])
    js = [codec.decode_payload(jcls, m.payload) for m in rec.messages(joint_topic)]
    ms = [codec.decode_payload(mcls, m.payload) for m in rec.messages(measurement_topic)]
    data = pair_streams(js, ms, max_interp_gap_s=max_interp_gap_s)
    data.sensor = measurement_topic.strip("/").split("/")[0]
    data.source = f"{path} ({joint_topic} + {measurement_topic})"
    payload = payload_kg if payload_kg is not None else recorded_payload_kg(rec, robot_stage)
    if payload is not None:
        data = with_payload(data, payload)
    return data


def recorded_payload_kg(rec: Any, joint_stage: str) -> float | None:
    """The ``payload_kg`` parameter of the stage that published the joints, or else of the robot it
    commands (a measurement campaign publishes the joints of the robot stage it uses), from the
    recording's own recipe with its overrides; None when neither has one."""
    from engine.errors import RecipeError
    from engine.recipe import load_recipe

    if not rec.recipe_text:
        return None
    try:
        loaded = load_recipe(f"{rec.path}#recipe", list(rec.overrides), text=rec.recipe_text)
    except RecipeError:  # a recipe this version cannot read: the payload is then not known from it
        return None
    stages = loaded.recipe.stages
    first = stages.get(joint_stage)
    used = [] if first is None else [ref.split(".")[0] for ref in first.uses.values()]
    for name in (joint_stage, *used):
        value = stages[name].params.get("payload_kg") if name in stages else None
        if isinstance(value, int | float):
            return float(value)
    return None


def with_payload(data: GapData, payload_kg: float) -> GapData:
    """*data* with the same payload (kg at the TCP) at every sample; refuses to replace one it has."""
    if not (np.isfinite(payload_kg) and payload_kg >= 0):
        raise GapDataError(f"payload must be finite and >= 0 kg, got {payload_kg}")
    if data.samples.payload_kg is not None:
        raise GapDataError(f"{data.source or 'the data'} already has a payload per sample; not replacing it")
    data.samples = replace(data.samples, payload_kg=np.full(data.n_samples, float(payload_kg)))
    return data


def pair_streams(joint_states: list, measurements: list, *, max_interp_gap_s: float = 10.0) -> GapData:
    """Pair measurement messages (TrackerPose / PoseStamped) with JointState messages by stamp.

    Each measurement gets the joint state interpolated (linearly) at its stamp; measurements outside
    the joint stream's time span or marked invalid are skipped (with a warning). The range is
    ``|p|`` when every measurement is in one frame that is not a robot-side or world frame
    (:data:`NOT_SENSOR_FRAMES`): a TrackerPose or a point instrument's PoseStamped is in the
    instrument's own frame (``lighthouse``, ``tracker``, ``camera`` ...), whose origin is its centre.
    """
    if not joint_states or not measurements:
        raise GapDataError(f"{len(joint_states)} joint states and {len(measurements)} measurements: need both")
    js, ms = joint_states, measurements
    t_j = np.array([m.stamp_ns for m in js], dtype=np.int64)
    q_j = np.array([np.asarray(m.positions, dtype=float) for m in js])
    order = np.argsort(t_j, kind="stable")
    t_j, q_j = t_j[order], q_j[order]
    v_j = None
    if all(m.velocities is not None for m in js):
        v_j = np.array([np.asarray(m.velocities, dtype=float) for m in js])[order]
    valid = [m for m in ms if getattr(m, "valid", True)]
    dropped = len(ms) - len(valid)
    t_m = np.array([m.stamp_ns for m in valid], dtype=np.int64)
    p_m = np.array([np.asarray(m.T)[:3, 3] for m in valid]).reshape(-1, 3)
    inside = (t_m >= t_j[0]) & (t_m <= t_j[-1])
    warnings = []
    if dropped:
        warnings.append(f"{dropped} invalid measurements (tracking lost) skipped")
    if np.any(~inside):
        warnings.append(f"{int(np.sum(~inside))} measurements outside the joint stream's time span skipped")
    t_m, p_m = t_m[inside], p_m[inside]
    if t_m.size == 0:
        raise GapDataError("no measurement falls within the joint stream's time span")
    frames = {str(getattr(m, "frame_id", "") or "") for m, ok in zip(valid, inside, strict=True) if ok}
    range_m = None
    if len(frames) == 1 and not (frames & NOT_SENSOR_FRAMES) and np.all(np.linalg.norm(p_m, axis=1) > 0):
        range_m = np.linalg.norm(p_m, axis=1)  # the instrument's own frame: its centre is the origin
    else:
        warnings.append(
            f"no range derived (depth_scale / depth_bias not testable): the measurements are in frame(s) "
            f"{sorted(frames)}, not one instrument frame"
        )
    k = np.clip(np.searchsorted(t_j, t_m, side="right") - 1, 0, len(t_j) - 1)
    k1 = np.minimum(k + 1, len(t_j) - 1)
    span = (t_j[k1] - t_j[k]).astype(float)
    a = np.where(span > 0, (t_m - t_j[k]) / np.where(span > 0, span, 1.0), 0.0)
    far = (span / 1e9 > max_interp_gap_s) & (a > 0)
    if np.any(far):
        warnings.append(f"{int(far.sum())} measurements between joint states > {max_interp_gap_s} s apart")
    q = q_j[k] + a[:, None] * (q_j[k1] - q_j[k])
    if v_j is not None:
        qd = v_j[k] + a[:, None] * (v_j[k1] - v_j[k])
    else:
        dq = np.diff(q_j, axis=0)
        dt = np.diff(t_j).astype(float)[:, None] / 1e9
        rate = np.divide(dq, dt, out=np.zeros_like(dq), where=dt > 0)
        qd = np.vstack([rate, np.zeros((1, q_j.shape[1]))])[k]
    direction = _approach_directions(q_j, k, qd)
    t_s = (t_m - t_j[0]) / 1e9
    try:
        samples = KinematicSamples(q, p_m, None, t_s, direction)
        return GapData(samples, qd=qd, range_m=range_m, warnings=warnings)
    except ValueError as e:
        raise GapDataError(f"paired samples are unusable: {e}") from None


def _approach_directions(q_states: F64, k: np.ndarray, qd: F64) -> F64:
    """Per joint: sign of the current velocity, else of the last change of the joint before the sample."""
    n = q_states.shape[1]
    last = np.ones((len(q_states), n))
    cur = np.ones(n)
    for i in range(1, len(q_states)):
        d = q_states[i] - q_states[i - 1]
        cur = np.where(np.abs(d) > 1e-9, np.sign(d), cur)
        last[i] = cur
    out = last[k]
    moving = np.abs(qd) > 1e-9
    return np.where(moving, np.sign(qd), out)


def load_gap_data(path: str | Path, *, payload_kg: float | None = None, **kw) -> GapData:
    """CSV or MCAP by file suffix. *payload_kg* (kg at the TCP, every sample) replaces what a
    recording's recipe says; a CSV with a ``payload_kg`` column keeps its own and refuses it."""
    p = Path(path)
    if p.suffix.lower() == ".mcap":
        opts = {k: v for k, v in kw.items() if k in ("joint_topic", "measurement_topic")}
        return read_gap_mcap(p, payload_kg=payload_kg, **opts)
    if p.suffix.lower() in (".csv", ".txt"):
        data = read_gap_csv(p, **{k: v for k, v in kw.items() if k == "sensor"})
        return data if payload_kg is None else with_payload(data, payload_kg)
    raise GapDataError(f"{p}: unknown data format {p.suffix!r}; give a .csv file or a .mcap recording")
