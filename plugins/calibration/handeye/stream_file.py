"""Hand-eye data as two stamped pose streams in one JSON file (``vgr.handeye.streams/1``), paired
by plugins/calibration/handeye/streams.py with the clock offset estimated (or as the file says)::

    {"format": "vgr.handeye.streams/1", "length_unit": "m", "setup": "eye_in_hand",
     "clock_offset_s": null,                      # robot time - camera time; null: estimate it
     "robot":  [{"stamp_s": 12.008, "T_base_tcp": POSE}, ...],
     "camera": [{"stamp_s": 12.031, "T_cam_target": POSE}, ...]}   # optional "camera_cov" / "camera_sigma"

POSE as in the samples format (plugins/calibration/handeye/io.py: a 4x4 nested list,
``{"position", "quat_xyzw"}`` or ``{"position", "rotvec"}``). The two streams need not be paired or
of one rate; each must be in time order. Up to MAX_STREAM_SAMPLES paired samples, evenly spread in
time, go to the solver (neighbours of a fast stream say nearly the same). A camera entry whose pose
is missing (``null``, or every number NaN: no detection in that frame) is dropped and counted.
Without ``setup`` the offset is estimated for both set-ups and the one whose pose chains agree
better is taken. A camera entry may carry its pose's covariance, ``camera_cov`` (36 numbers) or
``camera_sigma`` (6), as a sample of the samples format does
(plugins/calibration/handeye/covariance_file.py: every entry or none, the file's length unit); the
paired samples keep their camera entry's (``PoseSamples.camera_covariances``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plugins.calibration.handeye.covariance_file import covariance_entry, covariances_in_metres
from plugins.calibration.handeye.io import STREAMS_FORMAT, PoseSamples, load_pose_pairs, pose_from_json, unit_scale
from plugins.calibration.handeye.problem import SETUPS, Setup, check_setup
from plugins.calibration.handeye.streams import OffsetFit, PoseStream, fit_offset, paired
from plugins.calibration.handeye.validation import HandEyeInputError

F64 = NDArray[np.float64]
MAX_STREAM_SAMPLES = 200  # samples handed to the solver (its closed forms use every pair of them)


def _stream(path: Path, entries: Any, key: str, scale: float) -> tuple[PoseStream, int, F64 | None]:
    """The stream of *entries* (``stamp_s`` + *key*), translations times *scale*; how many entries
    had no pose; and the covariances the entries with a pose carry, in metres (None: none do)."""
    if not isinstance(entries, list) or not entries:
        raise HandEyeInputError(f"{path}: {key.split('_', 1)[0]} stream: a non-empty list of entries is needed")
    stamps, poses, missing = [], [], 0
    covs: list[F64 | None] = []
    for k, e in enumerate(entries):
        where = f"{path} {key} entry {k}"
        if not isinstance(e, dict) or "stamp_s" not in e or key not in e:
            raise HandEyeInputError(f"{where}: needs 'stamp_s' and '{key}'")
        T = None if e[key] is None else pose_from_json(e[key], where)
        if T is None or np.isnan(T[:3]).all():
            missing += 1
            continue
        stamps.append(float(e["stamp_s"]))
        poses.append(T)
        if key == "T_cam_target":  # (a camera entry's own covariance)
            covs.append(covariance_entry(e.get("camera_cov"), e.get("camera_sigma"), where))
    T = np.array(poses)
    T[:, :3, 3] *= scale
    cov = covariances_in_metres(covs, [f"{key} entry at {t:.3f} s" for t in stamps], scale, path) if covs else None
    try:
        return PoseStream(np.array(stamps), T), missing, cov
    except ValueError as exc:
        raise HandEyeInputError(f"{path}: {key}: {exc}") from None


def load_samples(path: str | Path, *, length_unit: str | None = None) -> PoseSamples:
    """Samples from any hand-eye file: a ``vgr.handeye.streams/1`` file paired here, the others by
    plugins.calibration.handeye.io.load_pose_pairs."""
    if Path(path).suffix.lower() == ".json":
        try:
            doc = json.loads(Path(path).read_text())
        except (OSError, ValueError):
            doc = None  # (load_pose_pairs says what is wrong with it)
        if isinstance(doc, dict) and doc.get("format") == STREAMS_FORMAT:
            return load_streams_json(path, doc)
    return load_pose_pairs(path, length_unit=length_unit)


def load_streams_json(path: str | Path, data: dict[str, Any] | None = None) -> PoseSamples:
    """The samples of a ``vgr.handeye.streams/1`` file (:func:`pair_streams`); ``notes`` say the
    offset and what was dropped, ``metrics`` the offset and its 1-sigma in seconds."""
    path = Path(path)
    doc = data if data is not None else json.loads(path.read_text())
    scale = unit_scale(doc.get("length_unit", "m"))
    robot, _, _ = _stream(path, doc.get("robot"), "T_base_tcp", scale)
    camera, missing, camera_cov = _stream(path, doc.get("camera"), "T_cam_target", scale)
    setup: Setup | None = check_setup(doc["setup"]) if doc.get("setup") else None
    known = doc.get("clock_offset_s")
    samples = pair_streams(
        robot, camera, setup=setup, clock_offset_s=None if known is None else float(known), source=str(path),
        camera_covariances=camera_cov,
    )  # fmt: skip
    if missing:
        samples.notes.insert(0, f"{missing} camera frame(s) without a pose dropped")
    return samples


def pair_streams(
    robot: PoseStream,
    camera: PoseStream,
    *,
    setup: Setup | None = None,
    clock_offset_s: float | None = None,
    source: str = "",
    camera_covariances: F64 | None = None,
) -> PoseSamples:
    """Hand-eye samples from a robot and a camera stream: the camera poses with the robot's
    interpolated at their stamps plus the clock offset (``robot_time = camera_time + offset``),
    estimated when *clock_offset_s* is None (for *setup*, or for the set-up whose pose chains agree
    better). At most MAX_STREAM_SAMPLES, evenly spread in time. ``metrics``: ``clock_offset_s`` and,
    when estimated, ``clock_offset_sd_s``; ``notes`` say so and what was dropped.
    *camera_covariances* ``(n_camera, 6, 6)``: each camera pose's, kept with it
    (``PoseSamples.camera_covariances``)."""
    metrics: dict[str, float] = {}
    if clock_offset_s is not None:
        offset = float(clock_offset_s)
        notes = [f"clock offset {offset * 1e3:.3f} ms (robot - camera), as {'the file says' if source else 'given'}"]
    else:
        fit, setup = _estimated(source, setup, robot, camera)
        offset = fit.offset_s
        metrics["clock_offset_sd_s"] = fit.sigma_s
        notes = [
            f"clock offset {fit.offset_s * 1e3:.3f} ± {fit.sigma_s * 1e3:.3f} ms (robot - camera), estimated "
            f"(cross-correlation start {fit.coarse_s * 1e3:.1f} ms)"
        ]
    metrics["clock_offset_s"] = offset
    M, B, ok = paired(robot, camera, offset)
    cov = None
    if camera_covariances is not None:
        cov = np.asarray(camera_covariances, dtype=float)
        if cov.shape != (len(ok), 6, 6):
            raise HandEyeInputError(f"{len(cov)} camera covariances for {len(ok)} camera poses: one 6x6 per pose")
        cov = cov[ok]
    if ok.sum() < len(ok):
        notes.append(f"{int((~ok).sum())} camera pose(s) outside the robot stream (or across a gap in it) dropped")
    stamps = camera.stamps_s[ok]
    if len(M) > MAX_STREAM_SAMPLES:  # neighbours of a 30 Hz stream say nearly the same: spread them out
        take = np.unique(np.linspace(0, len(M) - 1, MAX_STREAM_SAMPLES).round().astype(int))
        notes.append(f"{len(take)} of the {len(M)} paired camera poses used, evenly spread in time")
        M, B, stamps = M[take], B[take], stamps[take]
        cov = None if cov is None else cov[take]
    ids = [f"t={t:.3f}s" for t in stamps]
    samples = PoseSamples(M, B, ids, setup, source, camera_covariances=cov)
    samples.notes.extend(notes)
    samples.metrics.update(metrics)
    return samples


def _estimated(source: str, setup: Setup | None, robot: PoseStream, camera: PoseStream) -> tuple[OffsetFit, Setup]:
    """The offset fit for *setup*, or for the set-up whose pose chains agree better when None."""
    try:
        fits = {s: fit_offset(s, robot, camera) for s in ((setup,) if setup else SETUPS)}
    except ValueError as exc:
        raise HandEyeInputError(f"{source or 'streams'}: {exc}") from None
    best = min(fits, key=lambda s: fits[s].chain_rms_m)
    return fits[best], best
