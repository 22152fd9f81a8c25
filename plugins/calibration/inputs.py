"""Calibration data from bus messages and recordings, shared by the solver stages and ``vgr calibrate``.

Owns three things:

* **pairing** (:func:`pair_by_stamp_or_order`): a calibration sample is two measurements taken at
  the same moment (robot pose + target pose, joint state + measured point, fixture contact +
  tracker pose) that arrive as two message streams. ``mode="stamp"`` (default) pairs each sample of
  the *primary* stream (the robot side) with the nearest-in-time unused message of the secondary
  stream within ``max_skew_s``; extra secondary messages (a streaming tracker) are ignored. A
  primary message without a partner is an error unless ``drop_unmatched`` (then it is dropped and
  said so). ``mode="order"`` pairs the k-th with the k-th: the counts must be equal and each pair's
  stamps within ``max_skew_s`` (``max_skew_s=None`` skips that check).
* **conversions** from message lists to the libraries' data classes
  (:func:`hand_eye_samples`, :func:`vive_desk_data`, :func:`tcp_camera_data`,
  :func:`kinematic_samples`);
* **reading a topic of a vgr MCAP recording** (:func:`read_topic`) with errors that list the
  topics of the wanted type.

Problems raise :class:`CalibrationInputError` (a ``ValueError``) with a message a user can act on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, TypedDict, TypeVar, Unpack

import numpy as np

from engine.messages import JointState, Message, PoseStamped, PoseWithCovarianceStamped, TrackerPose, codec
from engine.recording.reader import Recording
from plugins.calibration.handeye.io import PoseSamples
from plugins.calibration.handeye.noise import check_camera_covariances
from plugins.calibration.kinematics import KinematicSamples
from plugins.calibration.tcp_camera import TcpCameraData, TcpNoiseModel
from plugins.calibration.vive_desk import ViveDeskData, ViveNoiseModel

PairMode = Literal["stamp", "order"]
MsgT = TypeVar("MsgT", bound=Message)


class PairingOptions(TypedDict, total=False):
    """How the conversions pair their two streams (:func:`pair_by_stamp_or_order`'s keywords)."""

    mode: PairMode
    max_skew_s: float | None
    drop_unmatched: bool


class CalibrationInputError(ValueError):
    """The messages or the recording cannot be turned into calibration samples (says why)."""


@dataclass
class Pairing:
    """Indices of paired messages (primary, secondary) and notes for the user."""

    pairs: list[tuple[int, int]]
    notes: list[str] = field(default_factory=list)


def _fmt_s(ns: int) -> str:
    return f"{ns / 1e9:.3f} s"


def pair_by_stamp_or_order(
    primary_stamps: Sequence[int],
    secondary_stamps: Sequence[int],
    *,
    names: tuple[str, str] = ("primary", "secondary"),
    mode: PairMode = "stamp",
    max_skew_s: float | None = 0.05,
    drop_unmatched: bool = False,
) -> Pairing:
    """Pair two message streams by their stamps (integer ns); see the module docstring."""
    a = np.asarray(primary_stamps, dtype=np.int64)
    b = np.asarray(secondary_stamps, dtype=np.int64)
    na, nb = names
    if mode == "order":
        if len(a) != len(b):
            raise CalibrationInputError(
                f"{len(a)} {na} but {len(b)} {nb}: pairing by order needs equal counts "
                "(pair by stamp instead, or check which samples are missing)"
            )
        if max_skew_s is not None and len(a):
            skew = np.abs(a - b)
            bad = np.flatnonzero(skew > max_skew_s * 1e9)
            if bad.size:
                k = int(bad[0])
                raise CalibrationInputError(
                    f"pair {k}: {na} stamped {_fmt_s(int(a[k]))} but {nb} {_fmt_s(int(b[k]))} "
                    f"({skew[k] / 1e9:.3f} s apart > max skew {max_skew_s} s; {bad.size} such pair(s)): "
                    "the streams are not aligned sample by sample"
                )
        return Pairing([(k, k) for k in range(len(a))])
    if mode != "stamp":
        raise CalibrationInputError(f"pairing mode must be 'stamp' or 'order', got {mode!r}")
    tol = np.inf if max_skew_s is None else max_skew_s * 1e9
    used = np.zeros(len(b), dtype=bool)
    pairs: list[tuple[int, int]] = []
    unmatched: list[int] = []
    for i, s in enumerate(a):
        if not len(b):
            unmatched.append(i)
            continue
        d = np.abs(b - s).astype(float)
        d[used] = np.inf
        j = int(np.argmin(d))
        if d[j] <= tol:
            used[j] = True
            pairs.append((i, j))
        else:
            unmatched.append(i)
    notes: list[str] = []
    if unmatched:
        first = ", ".join(_fmt_s(int(a[i])) for i in unmatched[:5])
        text = (
            f"{len(unmatched)} of {len(a)} {na} have no {nb} within "
            f"{max_skew_s} s (stamps {first}{' ...' if len(unmatched) > 5 else ''})"
        )
        if not drop_unmatched:
            raise CalibrationInputError(
                text + ": a missed detection or a wrong topic? (drop them explicitly to calibrate with the "
                f"{len(pairs)} matched pairs)"
            )
        notes.append(text + "; dropped")
    extra = int(len(b) - used.sum())
    if extra and mode == "stamp" and pairs:
        notes.append(f"{extra} {nb} not paired with any {na} (ignored)")
    return Pairing(pairs, notes)


def _stamps(msgs: Sequence[Message]) -> list[int]:
    return [int(m.stamp_ns) for m in msgs]


def _pair(
    primary: Sequence[Message], secondary: Sequence[Message], names: tuple[str, str], **options: Unpack[PairingOptions]
) -> Pairing:
    if not primary:
        raise CalibrationInputError(f"no {names[0]}")
    if not secondary:
        raise CalibrationInputError(f"no {names[1]}")
    pairing = pair_by_stamp_or_order(_stamps(primary), _stamps(secondary), names=names, **options)
    if not pairing.pairs:
        raise CalibrationInputError(f"no {names[0]} could be paired with {names[1]}")
    return pairing


def _poses(msgs: Sequence[PoseStamped] | Sequence[TrackerPose], idx: Sequence[int]) -> np.ndarray:
    """The 4x4 ``T`` of the messages at *idx*, stacked."""
    return np.array([np.asarray(msgs[i].T, dtype=float) for i in idx])


def hand_eye_samples(
    robot: Sequence[PoseStamped],
    target: Sequence[PoseStamped],
    **pairing: Unpack[PairingOptions],
) -> tuple[PoseSamples, list[str]]:
    """Robot poses ``T_base_tcp`` + camera observations ``T_cam_target`` -> hand-eye samples; when every
    paired target pose carries a covariance (PoseWithCovarianceStamped), the samples carry them
    (``PoseSamples.camera_covariances``), unless one is no covariance (then a note says so)."""
    p = _pair(robot, target, ("robot poses", "target poses"), **pairing)
    M = _poses(robot, [i for i, _ in p.pairs])
    B = _poses(target, [j for _, j in p.pairs])
    ids = [f"t={robot[i].stamp_ns / 1e9:.3f}s" for i, _ in p.pairs]
    seen = [target[j] for _, j in p.pairs]
    cov = None
    if all(isinstance(m, PoseWithCovarianceStamped) for m in seen):
        try:
            cov = check_camera_covariances([m.covariance for m in seen], names=ids)  # type: ignore[attr-defined]
        except ValueError as exc:
            p.notes.append(f"the target poses' covariances are not used per sample: {exc}")
    return PoseSamples(M, B, ids, None, "messages", camera_covariances=cov), p.notes


def vive_desk_data(
    contacts: Sequence[PoseStamped],
    trackers: Sequence[TrackerPose],
    *,
    noise: ViveNoiseModel | None = None,
    **pairing: Unpack[PairingOptions],
) -> tuple[ViveDeskData, list[str]]:
    """Fixture contacts + tracker poses -> Vive desk data.

    A contact message is ``T_desktop_tcp``: where the fixture holds the TCP, in the desk frame
    (translation = contact point + TCP offset, rotation = fixture orientation). Tracker readings
    flagged invalid are left out before pairing.
    """
    notes: list[str] = []
    valid = [t for t in trackers if t.valid]
    if len(valid) < len(trackers):
        notes.append(f"{len(trackers) - len(valid)} tracker reading(s) flagged invalid (tracking lost) left out")
    p = _pair(contacts, valid, ("fixture contacts", "tracker poses"), **pairing)
    T_dc = _poses(contacts, [i for i, _ in p.pairs])
    T_bt = _poses(valid, [j for _, j in p.pairs])
    data = ViveDeskData.from_contacts(
        T_dc[:, :3, 3],
        T_bt,
        tcp_offsets_desktop=np.zeros((len(T_dc), 3)),
        R_desktop_tcp=T_dc[:, :3, :3],
        noise=noise,
        labels=[f"C{k + 1}" for k in range(len(T_dc))],
    )
    return data, notes + p.notes


def tcp_camera_data(
    robot: Sequence[PoseStamped],
    points: Sequence[PoseStamped],
    *,
    noise: TcpNoiseModel | None = None,
    **pairing: Unpack[PairingOptions],
) -> tuple[TcpCameraData, list[str]]:
    """Robot poses (``T_base_flange``: the frame whose TCP offset is calibrated) + the TCP point seen
    by the camera (the translation of each point message, camera frame) -> TCP-by-camera data."""
    p = _pair(robot, points, ("robot poses", "camera points"), **pairing)
    T = _poses(robot, [i for i, _ in p.pairs])
    P = _poses(points, [j for _, j in p.pairs])[:, :3, 3]
    return TcpCameraData.from_arrays(T, P, noise=noise), p.notes


def kinematic_samples(
    joints: Sequence[JointState],
    points: Sequence[PoseStamped],
    *,
    full_pose: bool = False,
    **pairing: Unpack[PairingOptions],
) -> tuple[KinematicSamples, list[str]]:
    """Joint states (rad) + measured tool points (instrument frame; with ``full_pose`` also the
    measured tool orientation) -> kinematic calibration samples."""
    p = _pair(joints, points, ("joint states", "measurements"), **pairing)
    n_joints = {len(joints[i].positions) for i, _ in p.pairs}
    if len(n_joints) != 1:
        raise CalibrationInputError(f"joint states have different numbers of joints: {sorted(n_joints)}")
    q = np.array([np.asarray(joints[i].positions, dtype=float) for i, _ in p.pairs])
    T = _poses(points, [j for _, j in p.pairs])
    return KinematicSamples(q, T[:, :3, 3], T[:, :3, :3] if full_pose else None), p.notes


def min_kinematic_samples(dof: int, full_pose: bool) -> int:
    """Fewest samples whose equations outnumber the unknowns of a complete, minimal kinematic model
    (4 per revolute joint + 6 for the measurement frame and tool, 3 fewer for a tool point)."""
    unknowns = 4 * dof + (6 if full_pose else 3)
    return unknowns // (6 if full_pose else 3) + 1


def read_topic(recording: Recording, topic: str, expected: type[MsgT]) -> list[MsgT]:
    """Decoded messages of *topic* in a loaded recording (:func:`engine.recording.reader.load`), file order.

    Raises CalibrationInputError naming the topics that carry *expected* when *topic* is absent,
    of another type or empty.
    """
    channels = recording.channels
    of_type = sorted(t for t, meta in channels.items() if meta.get("type") == expected.TYPE)
    hint = f"topics with {expected.TYPE} messages: {', '.join(of_type) or 'none'}"
    if topic not in channels:
        raise CalibrationInputError(f"{recording.path}: no topic {topic!r} ({hint})")
    got = channels[topic].get("type", "")
    if got != expected.TYPE:
        raise CalibrationInputError(
            f"{recording.path}: topic {topic!r} carries {got or 'unknown'} messages, not {expected.TYPE} ({hint})"
        )
    msgs = [codec.decode_payload(expected, m.payload) for m in recording.messages(topic)]
    if not msgs:
        raise CalibrationInputError(f"{recording.path}: topic {topic!r} has no messages")
    return msgs  # type: ignore[return-value]
