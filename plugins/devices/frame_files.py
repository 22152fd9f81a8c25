"""Point-cloud frames stored as files: PLY and PCD (read by Open3D) and NPZ (numpy), one frame a file.

NPZ keys (``numpy.savez``; any other key is an error, so a misspelt key is not silently ignored):

==========  ==========================  ===================================================
key         shape / dtype               meaning
==========  ==========================  ===================================================
points      (N, 3) or (H, W, 3) float   points in the camera frame; NaN/inf rows dropped
normals     same shape as points        optional unit normals
colors      same shape, uint8 0..255    optional RGB (float 0..1 is accepted and converted)
            or float 0..1
depth       (H, W) float or uint16      depth along the optical axis, file units; <= 0 or
                                        NaN = no measurement
K           (3, 3)                      pinhole intrinsics of ``depth`` (needed with depth)
==========  ==========================  ===================================================

A file needs ``points``, or ``depth`` with ``K`` (the cloud is then deprojected, see
:mod:`plugins.camera.depth_projection`); with both, ``points`` is the cloud and ``depth``/``K`` are
published as the depth image. Lengths are multiplied by ``unit_scale_m`` (metres per file unit:
1 for metres, 0.001 for millimetres).

Order: files are played in natural order of their names (``f2`` before ``f10``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from plugins.camera.depth_projection import deproject_depth, valid_points
from plugins.camera.pinhole import CameraModel
from plugins.devices.camera_output import CameraFrame

FRAME_SUFFIXES = (".ply", ".pcd", ".npz")
NPZ_KEYS = ("points", "normals", "colors", "depth", "K")


class FrameFileError(ValueError):
    """A frame file cannot be used; the message names the file and why."""


def natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def list_frame_files(folder: str | Path, pattern: str = "*") -> list[Path]:
    """PLY/PCD/NPZ files in *folder* matching *pattern*, in natural name order."""
    root = Path(folder)
    if not root.is_dir():
        raise FrameFileError(f"frame folder {root} does not exist or is not a folder")
    matched = [p for p in root.glob(pattern) if p.is_file()]
    frames = sorted((p for p in matched if p.suffix.lower() in FRAME_SUFFIXES), key=natural_key)
    if not frames:
        others = ", ".join(sorted(p.name for p in matched)[:5]) or "no files at all"
        raise FrameFileError(
            f"no PLY/PCD/NPZ frame files in {root} matching {pattern!r} ({others} matched the pattern)"
        )
    return frames


def _colors_u8(colors: np.ndarray, path: Path) -> np.ndarray:
    c = np.asarray(colors)
    if c.dtype == np.uint8:
        return c
    c = c.astype(float)
    if not np.all(np.isfinite(c)) or c.min() < 0.0 or c.max() > 1.0:
        raise FrameFileError(f"{path}: colors must be uint8 0..255 or floats in [0, 1]")
    return np.round(c * 255.0).astype(np.uint8)


def _finite_rows(path: Path, points, normals, colors) -> CameraFrame:
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    keep = np.all(np.isfinite(pts), axis=1)
    nrm = None if normals is None else np.asarray(normals, dtype=float).reshape(-1, 3)[keep]
    col = None if colors is None else _colors_u8(colors, path).reshape(-1, 3)[keep]
    return CameraFrame(points=pts[keep], normals=nrm, colors=col, source=path.name)


def _load_open3d(path: Path) -> CameraFrame:
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    if len(pc.points) == 0:
        raise FrameFileError(f"{path}: Open3D read no points (unreadable, empty, or not a {path.suffix} point cloud)")
    normals = np.asarray(pc.normals) if pc.has_normals() else None
    colors = np.asarray(pc.colors) if pc.has_colors() else None
    return _finite_rows(path, np.asarray(pc.points), normals, colors)


def _load_npz(path: Path) -> CameraFrame:
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:
        raise FrameFileError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from exc
    unknown = sorted(set(data) - set(NPZ_KEYS))
    if unknown:
        raise FrameFileError(f"{path}: unknown keys {unknown}; allowed: {', '.join(NPZ_KEYS)}")
    shape_of = {k: np.shape(v) for k, v in data.items()}
    if "points" in data:
        pts = data["points"]
        if pts.ndim not in (2, 3) or pts.shape[-1] != 3:
            raise FrameFileError(f"{path}: points must be (N, 3) or (H, W, 3), got {pts.shape}")
        for k in ("normals", "colors"):
            if k in data and data[k].shape != pts.shape:
                raise FrameFileError(f"{path}: {k} has shape {data[k].shape}, points {pts.shape}")
        frame = _finite_rows(path, pts, data.get("normals"), data.get("colors"))
    elif "depth" in data:
        if "K" not in data:
            raise FrameFileError(f"{path}: has 'depth' but no 'K' (3x3 intrinsics) to deproject it")
        frame = CameraFrame(points=np.zeros((0, 3)), source=path.name)
    else:
        raise FrameFileError(f"{path}: needs 'points', or 'depth' with 'K' (keys found: {shape_of})")
    if "depth" in data:
        depth = np.asarray(data["depth"], dtype=np.float64)
        if depth.ndim != 2:
            raise FrameFileError(f"{path}: depth must be (H, W), got {depth.shape}")
        if "K" not in data:
            raise FrameFileError(f"{path}: has 'depth' but no 'K' (3x3 intrinsics)")
        try:
            intr = CameraModel(depth.shape[1], depth.shape[0], np.asarray(data["K"], dtype=float), np.zeros(5))
        except ValueError as exc:
            raise FrameFileError(f"{path}: {exc}") from exc
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
        frame.depth_m, frame.intrinsics = depth, intr
        if "points" not in data:
            organised = deproject_depth(depth, intr)
            keep = np.all(np.isfinite(organised.reshape(-1, 3)), axis=1)
            frame.points = valid_points(organised)
            if "colors" in data:
                colors = _colors_u8(data["colors"], path)
                if colors.shape != (*depth.shape, 3):
                    raise FrameFileError(f"{path}: colors {colors.shape} do not match depth {depth.shape}")
                frame.colors = colors.reshape(-1, 3)[keep]
            if "normals" in data:
                raise FrameFileError(f"{path}: normals need 'points' (a depth image has no normals to attach)")
    return frame


def load_frame(path: str | Path, unit_scale_m: float = 1.0) -> CameraFrame:
    """Read one frame file; lengths scaled to metres by *unit_scale_m*."""
    path = Path(path)
    if not path.is_file():
        raise FrameFileError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        frame = _load_npz(path)
    elif suffix in (".ply", ".pcd"):
        frame = _load_open3d(path)
    else:
        raise FrameFileError(f"{path}: unsupported frame file type {suffix!r} (use {', '.join(FRAME_SUFFIXES)})")
    if unit_scale_m != 1.0:
        frame.points = frame.points * unit_scale_m
        if frame.depth_m is not None and frame.intrinsics is not None:
            frame.depth_m = frame.depth_m * unit_scale_m
    if frame.depth_m is not None:
        frame.depth_m = frame.depth_m.astype(np.float32)
    return frame
