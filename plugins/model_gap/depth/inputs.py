"""What ``vgr gap --depth`` reads: depth captures of a flat target, from a captures file, a folder of
them, or a vgr recording.

**Captures file** (``.npz``, format ``vgr.depth_captures/1``, :func:`write_captures` writes one):
``depth`` (n, H, W) or (H, W) float, z along the optical axis in metres, NaN or 0 where invalid
(what a RealSense / Azure Kinect depth frame times its depth unit is); ``K`` (3, 3) of the depth
image; optional ``D`` (its distortion, OpenCV's order; a rectified depth stream has none),
``T_cam_target`` (n, 4, 4) the target's pose in the camera frame per capture (its plane is the
target frame's ``z = 0``: a board's pose from ``cv2.solvePnP`` on the registered IR / colour image),
``target_extent_m`` (4,) ``x_min, x_max, y_min, y_max`` of the target in its frame, ``names`` (n,),
``sigma_const_m`` and ``sigma_quad_per_m`` (the sensor's stated noise law). A **folder** holds such
files, one capture or more each, read in name order (they must share ``K``).

**Recording** (``.mcap`` of a ``vgr run``): the depth images (``Image``, ``32FC1``) on the ``topic``
given or the only ``.../depth`` topic, the intrinsics from the ``CameraInfo`` on the same stage's
``camera_info``; the target's pose from the stage's ``truth/part_poses`` (a simulated cell:
``target_frame`` names the target, the board or a plate, and the camera's true pose is the frame with
the depth images' ``frame_id``). Without a target frame the plane is fitted per capture. The target
should fill the image: the rest of the scene is not told apart from it (pixels far from its plane are
screened out as gross errors, a surface near it is not). Every refusal is a :class:`.data.DepthGapInputError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from plugins.model_gap.depth.data import DepthCaptures, DepthFrame, DepthGapInputError, SigmaLaw

__all__ = ["FORMAT", "load_captures", "write_captures"]

FORMAT = "vgr.depth_captures/1"


def write_captures(path: str | Path, captures: DepthCaptures) -> None:
    """*captures* as a ``vgr.depth_captures/1`` file (module docstring)."""
    arrays: dict[str, Any] = {
        "format": np.array(FORMAT),
        "depth": np.stack([np.asarray(f.depth, np.float32) for f in captures.frames]),
        "K": np.asarray(captures.K, float),
        "names": np.array([f.name for f in captures.frames]),
    }
    if all(f.T_cam_target is not None for f in captures.frames):
        arrays["T_cam_target"] = np.stack([np.asarray(f.T_cam_target, float) for f in captures.frames])
    extents = {f.target_extent_m for f in captures.frames}
    if len(extents) == 1 and None not in extents:
        arrays["target_extent_m"] = np.asarray(next(iter(extents)), float)
    if captures.D is not None:
        arrays["D"] = np.asarray(captures.D, float)
    if captures.sigma is not None:
        arrays["sigma_const_m"] = np.array(captures.sigma.const_m)
        arrays["sigma_quad_per_m"] = np.array(captures.sigma.quad_per_m)
    np.savez_compressed(path, **arrays)


def _array(doc: Any, key: str, path: Path, shape_ok: Any, what: str) -> np.ndarray:
    try:
        a = np.asarray(doc[key], dtype=float)
    except (ValueError, TypeError) as exc:
        raise DepthGapInputError(f"{path}: {key} is not numeric ({exc})") from None
    if not shape_ok(a):
        raise DepthGapInputError(f"{path}: {key} of shape {a.shape}: {what}")
    return a


def _read_npz(path: Path) -> DepthCaptures:
    try:
        doc = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DepthGapInputError(f"{path}: not a readable captures file ({exc})") from None
    with doc:
        keys = set(doc.files)
        if "format" in keys and str(doc["format"]) != FORMAT:
            raise DepthGapInputError(f"{path}: format {str(doc['format'])!r}, not {FORMAT}")
        for need in ("depth", "K"):
            if need not in keys:
                raise DepthGapInputError(f"{path}: no {need!r} array ({FORMAT}: depth (n, H, W) m and K (3, 3))")
        depth = _array(doc, "depth", path, lambda a: a.ndim in (2, 3) and a.size > 0, "need (n, H, W) or (H, W)")
        depth = depth[None] if depth.ndim == 2 else depth
        K = _array(doc, "K", path, lambda a: a.shape == (3, 3), "need (3, 3)")
        n = len(depth)
        poses = None
        if "T_cam_target" in keys:
            poses = _array(
                doc, "T_cam_target", path, lambda a: a.shape == (n, 4, 4) or (n == 1 and a.shape == (4, 4)),
                f"need ({n}, 4, 4): one pose per capture",
            ).reshape(n, 4, 4)  # fmt: skip
        extent = None
        if "target_extent_m" in keys:
            e = _array(doc, "target_extent_m", path, lambda a: a.shape == (4,), "need (x_min, x_max, y_min, y_max)")
            extent = (float(e[0]), float(e[1]), float(e[2]), float(e[3]))
        names = [str(s) for s in doc["names"]] if "names" in keys else [f"{path.stem}[{k}]" for k in range(n)]
        if len(names) != n:
            raise DepthGapInputError(f"{path}: {len(names)} names for {n} captures")
        D = _array(doc, "D", path, lambda a: a.ndim == 1, "need a vector") if "D" in keys else None
        sigma = None
        if "sigma_const_m" in keys or "sigma_quad_per_m" in keys:
            const = float(doc["sigma_const_m"]) if "sigma_const_m" in keys else 0.0
            sigma = SigmaLaw(const, float(doc["sigma_quad_per_m"]) if "sigma_quad_per_m" in keys else 0.0)
    frames = [DepthFrame(names[k], depth[k], None if poses is None else poses[k], extent) for k in range(n)]
    return DepthCaptures(frames, K, (depth.shape[2], depth.shape[1]), D, sigma, str(path))


def _merge(parts: Sequence[DepthCaptures], source: str) -> DepthCaptures:
    first = parts[0]
    for p in parts[1:]:
        if p.size != first.size or not np.allclose(p.K, first.K):
            raise DepthGapInputError(
                f"{p.source}: another camera (K or image size) than {first.source}: one camera only"
            )
    frames = [f for p in parts for f in p.frames]
    return DepthCaptures(frames, first.K, first.size, first.D, first.sigma, source)


def _frame_of(rec: Any, topic: str) -> list[Any]:
    from engine.messages import codec

    cls = codec.registry.get(rec.channels[topic].get("type", ""))
    return [codec.decode_payload(cls, m.payload) for m in rec.messages(topic)]


def _depth_topic(path: Path, types: dict[str, str], topic: str | None) -> str:
    """The recording's depth image topic: *topic* (an Image channel) or the only ``.../depth``."""
    if topic is not None:
        if types.get(topic) != "Image":
            images = sorted(t for t, ty in types.items() if ty == "Image")
            raise DepthGapInputError(f"{path}: no Image topic {topic!r} (Image topics: {', '.join(images) or 'none'})")
        return topic
    depth_topics = sorted(t for t, ty in types.items() if ty == "Image" and t.rstrip("/").endswith("/depth"))
    if len(depth_topics) != 1:
        raise DepthGapInputError(
            f"{path}: {len(depth_topics)} depth image topics {depth_topics}: need exactly one (or --topic)"
        )
    return depth_topics[0]


def _read_mcap(path: Path, target_frame: str | None, topic: str | None = None) -> DepthCaptures:
    from engine.recording.reader import RecordingError, load

    try:
        rec = load(path)
    except RecordingError as exc:
        raise DepthGapInputError(str(exc)) from None
    types = {t: meta.get("type", "") for t, meta in rec.channels.items()}
    depth_topic = _depth_topic(path, types, topic)
    stage = depth_topic.strip("/").split("/")[0]
    info_topic = f"/{stage}/camera_info"
    if types.get(info_topic) != "CameraInfo":
        raise DepthGapInputError(f"{path}: no CameraInfo on {info_topic}: the depth images' intrinsics are unknown")
    images = [m for m in _frame_of(rec, depth_topic) if m.encoding == "32FC1"]
    if not images:
        raise DepthGapInputError(f"{path}: no 32FC1 depth image on {depth_topic}")
    info = _frame_of(rec, info_topic)[0]
    truth: dict[int, dict[str, np.ndarray]] = {}
    if target_frame is not None:
        truth_topic = f"/{stage}/truth/part_poses"
        if types.get(truth_topic) != "FrameTransforms":
            raise DepthGapInputError(
                f"{path}: no {truth_topic}: the target's pose is not in this recording (leave out --target-frame)"
            )
        for msg in _frame_of(rec, truth_topic):
            truth[msg.stamp_ns] = {t.child_frame_id: np.asarray(t.T, float) for t in msg.transforms}
    frames = []
    for img in images:
        T = None
        if target_frame is not None:
            poses = truth.get(img.stamp_ns, {})
            cam, tgt = poses.get(f"truth/{img.frame_id}"), poses.get(f"truth/{target_frame}")
            if cam is None or tgt is None:
                known = sorted(n.removeprefix("truth/") for n in poses)
                raise DepthGapInputError(
                    f"{path}: capture at t = {img.stamp_ns} ns: no true pose of {target_frame!r} and the camera "
                    f"{img.frame_id!r} (frames: {', '.join(known) or 'none'})"
                )
            T = np.linalg.inv(cam) @ tgt
        frames.append(DepthFrame(f"{stage} t={img.stamp_ns / 1e9:.3f}s", np.asarray(img.data, float), T))
    D = np.asarray(info.D, float) if len(info.D) else None
    return DepthCaptures(frames, np.asarray(info.K, float), (int(info.width), int(info.height)), D, None, str(path))


def load_captures(
    inputs: Sequence[str],
    *,
    target_frame: str | None = None,
    topic: str | None = None,
    sigma: SigmaLaw | None = None,
) -> DepthCaptures:
    """The depth captures of the ``--depth`` inputs (module docstring); *sigma* overrides a file's
    stated noise law."""
    if not inputs:
        raise DepthGapInputError("--depth needs a captures file (.npz), a folder of them or a recording (.mcap)")
    parts = []
    for text in inputs:
        p = Path(text)
        if not p.exists():
            raise DepthGapInputError(f"--depth {text}: no such file or folder")
        if p.is_dir():
            files = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() == ".npz")
            if not files:
                raise DepthGapInputError(f"--depth {text}: the folder holds no .npz captures files")
            parts += [_read_npz(q) for q in files]
        elif p.suffix.lower() == ".npz":
            parts.append(_read_npz(p))
        elif p.suffix.lower() == ".mcap":
            parts.append(_read_mcap(p, target_frame, topic))
        else:
            raise DepthGapInputError(f"--depth {text}: not a captures file (.npz), a folder or a recording (.mcap)")
    out = _merge(parts, ", ".join(inputs))
    if sigma is not None:
        out.sigma = sigma
    return out
