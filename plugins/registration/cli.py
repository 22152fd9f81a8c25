"""``vgr template make|show``: make a matcher template from a recorded capture or a cloud file.

``make`` takes the capture from a recording (the ``--cloud-topic`` message number ``--index``,
with the photo pose from ``--pose-topic``: what ``capture_at_pose`` publishes) or from a PLY/PCD/NPZ
file (with ``--photo-pose``), crops the ROI, preprocesses, and writes ``DIR/NAME.vgrtpl`` (versioned
format, see plugins.registration.template: the cropped points are kept at full resolution).
``show`` prints what a template holds.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np
from rich.console import Console

from engine.exit_codes import ExitCode
from engine.messages import codec
from engine.transforms import as_transform
from plugins.registration.feature_frame import FeatureFrameParams
from plugins.registration.preprocess import PreprocessParams, RoiBox
from plugins.registration.template import load_template, make_template, save_template
from plugins.registration.validation import InvalidInputError
from plugins.vendor_poses import T_from_ur

out = Console()


def _vec3(text: str, name: str) -> tuple[float, float, float]:
    vals = [float(v) for v in text.replace(" ", "").split(",")]
    if len(vals) != 3 or not np.all(np.isfinite(vals)):
        raise InvalidInputError(f"{name} must be x,y,z in metres, got {text!r}")
    return (vals[0], vals[1], vals[2])


def _from_recording(path: str, cloud_topic: str, pose_topic: str, index: int) -> tuple[np.ndarray, np.ndarray]:
    from engine.recording.reader import load

    rec = load(path)
    clouds, poses = rec.messages(cloud_topic), rec.messages(pose_topic)
    if not clouds:
        counts = Counter(m.topic for m in rec.messages())
        have = [f"{t} ({counts[t]})" for t, meta in sorted(rec.channels.items()) if meta.get("type") == "PointCloud"]
        have = [h for h in have if not h.endswith(" (0)")]
        where = f"point-cloud topics with messages: {', '.join(have) or 'none'}"
        if cloud_topic in rec.channels:
            raise InvalidInputError(
                f"{path}: topic {cloud_topic} is in the recording but holds no message (its stage published "
                f"none in that run); {where}"
            )
        raise InvalidInputError(f"{path} has no topic {cloud_topic}; {where}")
    if index >= len(clouds) or index < -len(clouds):
        raise InvalidInputError(f"{cloud_topic} has {len(clouds)} messages; --index {index} is out of range")
    if len(poses) != len(clouds):
        raise InvalidInputError(f"{pose_topic} has {len(poses)} messages for {len(clouds)} clouds: cannot pair them")
    cloud = codec.decode_payload(codec.registry.get(clouds[index].type_name), clouds[index].payload)
    pose = codec.decode_payload(codec.registry.get(poses[index].type_name), poses[index].payload)
    return np.asarray(cloud.points, dtype=float), np.asarray(pose.T, dtype=float)


def _from_file(path: str) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"no such file: {p}")
    if p.suffix == ".npz":
        with np.load(p) as z:
            if "points" not in z:
                raise InvalidInputError(f"{p}: an NPZ capture needs a 'points' array (N, 3), has {list(z.keys())}")
            return np.asarray(z["points"], dtype=float)
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(str(p))
    if len(pcd.points) == 0:
        raise InvalidInputError(f"{p}: no points read (is it a PLY/PCD point cloud?)")
    return np.asarray(pcd.points, dtype=float)


def cmd_make(args: argparse.Namespace) -> int:
    try:
        if args.from_recording:
            points, T_photo = _from_recording(args.from_recording, args.cloud_topic, args.pose_topic, args.index)
        else:
            if not args.photo_pose:
                raise InvalidInputError("--from-file needs --photo-pose x,y,z,rx,ry,rz (m, rotation vector rad)")
            points = _from_file(args.from_file)
            vals = [float(v) for v in args.photo_pose.split(",")]
            if len(vals) != 6:
                raise InvalidInputError("--photo-pose must be 6 numbers: x,y,z,rx,ry,rz (m, rad)")
            T_photo = as_transform(T_from_ur(vals), name="photo pose")
        roi = None
        if args.roi_min or args.roi_max:
            if not (args.roi_min and args.roi_max):
                raise InvalidInputError("give both --roi-min and --roi-max")
            roi = RoiBox.from_bounds(_vec3(args.roi_min, "--roi-min"), _vec3(args.roi_max, "--roi-max"))
        pre = PreprocessParams(voxel_size_m=args.voxel_mm / 1e3, roi=roi)
        feature = FeatureFrameParams(
            feature_kind=args.feature_kind, radius_m=args.feature_radius_mm / 1e3 if args.feature_radius_mm else None
        )
        tpl = make_template(
            points,
            T_photo,
            name=args.name,
            kind=args.kind,
            preprocess=pre,
            feature_params=feature,
            metadata={"source": args.from_recording or args.from_file, "index": args.index},
        )
        path = save_template(tpl, args.output)
    except (InvalidInputError, ValueError, OSError) as exc:
        out.print(f"[red]error[/]: {exc}", highlight=False)
        return ExitCode.INVALID
    n = 0 if tpl.points is None else len(tpl.points)
    out.print(f"template {tpl.name!r} ({tpl.kind}, {n} points) written to {path}", highlight=False)
    return ExitCode.OK


def cmd_show(args: argparse.Namespace) -> int:
    try:
        tpl = load_template(args.path)
    except InvalidInputError as exc:
        out.print(f"[red]error[/]: {exc}", highlight=False)
        return ExitCode.INVALID
    info = {
        "name": tpl.name,
        "kind": tpl.kind,
        "schema_version": tpl.schema_version,
        "points": None if tpl.points is None else len(tpl.points),
        "points_resolution": tpl.points_resolution if tpl.points is not None else None,
        "T_base_tcp_photo": np.round(tpl.T_base_tcp_photo, 6).tolist(),
        "preprocess": tpl.preprocess,
        "metadata": tpl.metadata,
    }
    if tpl.points is not None:
        info["extent_mm"] = (np.ptp(tpl.points, axis=0) * 1e3).round(2).tolist()
    if args.json:
        print(json.dumps(info, indent=2, default=str))
    else:
        _print_template(info)
    return ExitCode.OK


def _print_template(info: dict) -> None:
    """A template's metadata as lines a person reads: sizes in mm, the photo pose as xyz + rpy."""
    from scipy.spatial.transform import Rotation

    T = np.asarray(info["T_base_tcp_photo"], dtype=float)
    xyz = ", ".join(f"{v * 1e3:.1f}" for v in T[:3, 3])
    rpy = ", ".join(f"{v:.2f}" for v in Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True))
    size = "" if info["points"] is None else f", {info['points']} points ({info['points_resolution']})"
    lines = [f"template {info['name']!r}: {info['kind']}{size}, schema {info['schema_version']}"]
    if "extent_mm" in info:
        lines.append("extent: " + " x ".join(f"{v:g}" for v in info["extent_mm"]) + " mm")
    lines.append(f"photo pose T_base_tcp: xyz ({xyz}) mm, rpy xyz ({rpy}) deg")
    pre = info["preprocess"] if isinstance(info["preprocess"], dict) else {}
    lines.append("preprocess: " + (", ".join(f"{k}={v}" for k, v in pre.items()) or "none"))
    for k, v in (info["metadata"] or {}).items():
        lines.append(f"  {k}: {v}")
    out.print("\n".join(lines), highlight=False, markup=False, soft_wrap=True)


def add_verbs(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("template", help="make or show a matcher template")
    tsub = p.add_subparsers(dest="template_verb", required=True)
    m = tsub.add_parser("make", help="make a template from a recorded capture or a cloud file")
    src = m.add_mutually_exclusive_group(required=True)
    src.add_argument("--from-recording", metavar="MCAP")
    src.add_argument("--from-file", metavar="CLOUD", help="PLY, PCD or NPZ (key 'points')")
    m.add_argument("--cloud-topic", default="/capture/cloud")
    m.add_argument("--pose-topic", default="/capture/pose")
    m.add_argument("--index", type=int, default=0, help="which capture of the recording (default the first)")
    m.add_argument("--photo-pose", help="with --from-file: T_base_tcp as x,y,z,rx,ry,rz (m, rotation vector)")
    m.add_argument("--name", required=True)
    m.add_argument("--kind", choices=["cloud", "feature_frame"], default="cloud")
    m.add_argument(
        "--voxel-mm",
        type=float,
        default=2.0,
        help="voxel the template is prepared at (default 2, the matcher stage's voxel_size_m); the points "
        "are stored at full resolution whatever it is",
    )
    m.add_argument("--roi-min", help="crop box corner x,y,z (m, camera frame)")
    m.add_argument("--roi-max")
    m.add_argument("--feature-kind", choices=["hole", "pin"], default="hole")
    m.add_argument("--feature-radius-mm", type=float)
    m.add_argument("-o", "--output", default="templates", help="directory for NAME.vgrtpl (default templates/)")
    m.set_defaults(func=cmd_make)
    s = tsub.add_parser("show", help="print a template's metadata")
    s.add_argument("path")
    s.add_argument("--json", action="store_true", help="print the metadata as JSON")
    s.set_defaults(func=cmd_show)
