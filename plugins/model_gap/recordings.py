"""Model-gap input from vgr recordings: joint states paired with measurements.

Recordings (MCAP written by ``vgr run``): the joints come from a ``JointState`` topic (the robot's
``/<robot>/joint_state``), the measurements from a ``TrackerPose`` or ``PoseStamped`` topic (position
of the measured point in the sensor frame, metres), e.g. ``/tracker/pose``. Each measurement is paired
with the joint state interpolated at its stamp; the joint velocities come from the JointState (or its
finite differences), the approach direction from the sign of each joint's last motion, ``t_s`` from
the first joint state, the range (depth effects) from ``|p|`` when the measurements are in the
instrument's own frame (see :func:`pair_streams`).
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

import numpy as np

from plugins.calibration.kinematics import KinematicSamples
from plugins.model_gap.data import F64, NOT_SENSOR_FRAMES, GapData, GapDataError, with_payload


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
    from engine.messages import codec
    from engine.recording.reader import RecordingError, load

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
    from engine.recipe.model import load_recipe

    if not rec.recipe_text:
        return None
    try:
        base = rec.recipe_dir or rec.path.parent  # (its plugin files are found from there)
        loaded = load_recipe(f"{rec.path}#recipe", list(rec.overrides), text=rec.recipe_text, base=base)
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
