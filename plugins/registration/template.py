"""Templates of seed 000: the reference a capture is matched against, stored with the photo pose.

A template is either a preprocessed CLOUD (method A: ``P_template``) or a FEATURE FRAME (method B:
``Frame_template``), both in the camera frame at capture time, plus ``T_base_tcp_photo`` (the robot's
TCP pose in its base frame when the template was captured; seed 000's ``T_photo_template``).

On-disk format (schema version 2): a directory ``<name>.vgrtpl/`` holding

* ``template.json`` -- ``schema`` ("vgr.template"), ``schema_version``, ``kind``, ``name``,
  ``T_base_tcp_photo`` (4x4, m), ``preprocess`` (parameters used, with the ROI), ``frame`` (feature
  frame, or null), ``points_file`` / ``points_sha256`` / ``n_points`` (cloud templates),
  ``points_resolution`` ("full"), ``metadata`` (free-form);
* ``points.npy`` -- (N, 3) float64 points in metres (cloud templates only; loaded without pickle):
  the capture cropped to the ROI and outlier-filtered, at FULL resolution (not downsampled), so
  that the fine stage can polish on every point and find the contour's edge points.

Version 1 (vgr before this change) stored the points downsampled at ``preprocess.voxel_size_m``;
such templates still load and match (``points_resolution`` reads "voxel"), but without the full-
resolution polish and with coarser edges: remake them with ``vgr template make`` (``make templates``
for the recipes' own).

A loader refuses unknown schemas, newer versions, checksum mismatches and invalid poses.
``make_template`` is the library entry point behind ``vgr template make``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from engine import transforms as tf
from plugins.registration.feature_frame import FeatureFrame, FeatureFrameParams, fit_feature_frame
from plugins.registration.preprocess import PreparedCloud, PreprocessParams, RoiBox, prepare_cloud
from plugins.registration.validation import InvalidInputError

SCHEMA = "vgr.template"
SCHEMA_VERSION = 2
SUFFIX = ".vgrtpl"


@dataclass
class Template:
    """A stored template (see module docstring). ``points`` for ``kind == "cloud"`` (full resolution
    unless ``points_resolution == "voxel"``: a version-1 template), ``frame`` for
    ``kind == "feature_frame"``."""

    kind: Literal["cloud", "feature_frame"]
    name: str
    T_base_tcp_photo: np.ndarray
    preprocess: dict[str, Any]
    points: np.ndarray | None = None
    frame: FeatureFrame | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION
    points_resolution: Literal["full", "voxel"] = "full"
    _prepared: PreparedCloud | None = field(default=None, init=False, repr=False, compare=False)

    def prepared(self) -> PreparedCloud:
        """The stored cloud as a :class:`PreparedCloud` for the matchers, built once per Template and
        then reused (its voxel grids, normals, k-d trees, edge points stay cached on it): downsampled
        at the template's voxel size, with the full-resolution points and the ROI kept for the
        polish and the edge term. A version-1 template (points already downsampled) is used as is."""
        if self.points is None:
            raise ValueError(f"template {self.name!r} is a {self.kind} template and holds no cloud")
        if self._prepared is None:
            pp = self.preprocess
            viewpoint = None if pp.get("viewpoint") is None else tuple(pp["viewpoint"])
            voxel, k = float(pp["voxel_size_m"]), int(pp["normal_k"])
            if self.points_resolution == "voxel":
                self._prepared = PreparedCloud(
                    points=self.points,
                    voxel_size_m=voxel,
                    normal_k=k,
                    viewpoint=viewpoint,
                    raw_count=int(self.points.shape[0]),
                    name="template",
                    roi=roi_from_dict(pp.get("roi")),
                )
            else:
                params = PreprocessParams(voxel_size_m=voxel, normal_k=k, viewpoint=viewpoint, min_points=1)
                self._prepared = prepare_cloud(self.points, params, name="template")
                self._prepared.roi = roi_from_dict(pp.get("roi"))
        return self._prepared


def _params_dict(p: PreprocessParams) -> dict[str, Any]:
    d = asdict(p)
    d["roi"] = None if p.roi is None else p.roi.to_dict()
    return d


def make_template(
    cloud: Any,
    T_base_tcp_photo: Any,
    *,
    name: str,
    kind: Literal["cloud", "feature_frame"] = "cloud",
    preprocess: PreprocessParams | None = None,
    feature_params: FeatureFrameParams | None = None,
    metadata: dict[str, Any] | None = None,
) -> Template:
    """Build a template from a capture: crop the ROI and remove outliers, check that it survives the
    downsampling (cloud: the full-resolution points are stored), or fit the feature frame
    (feature_frame). Raises InvalidInputError with a reason on bad input."""
    if not name or any(c in name for c in "/\\\0"):
        raise InvalidInputError(f"template name {name!r} must be non-empty without path separators")
    try:
        T_photo = tf.as_transform(T_base_tcp_photo, name="T_base_tcp_photo", tol=1e-5)
    except ValueError as exc:
        raise InvalidInputError(str(exc)) from exc
    if kind == "cloud":
        pp = preprocess or PreprocessParams()
        prep = prepare_cloud(cloud, pp, name="template")
        full = prep.full_points if prep.full_points is not None else prep.points
        return Template(kind, name, T_photo, _params_dict(pp), points=full, metadata=dict(metadata or {}))
    if kind == "feature_frame":
        fp = feature_params or FeatureFrameParams()
        if preprocess is not None:
            fp = FeatureFrameParams(**{**fp.__dict__, "preprocess": preprocess})
        frame = fit_feature_frame(cloud, fp)
        pp_dict = _params_dict(fp.preprocess)
        pp_dict["feature_params"] = {k: v for k, v in fp.__dict__.items() if k != "preprocess"}
        return Template(kind, name, T_photo, pp_dict, frame=frame, metadata=dict(metadata or {}))
    raise InvalidInputError(f"template kind must be 'cloud' or 'feature_frame', got {kind!r}")


def save_template(template: Template, directory: str | Path) -> Path:
    """Write ``<directory>/<name>.vgrtpl/`` (see module docstring) and return its path.

    The template is written into a temporary directory beside it and swapped in only when complete,
    so re-making a template that recipes use never leaves it half-written (points of the new one
    with the checksum of the old, which load_template would refuse)."""
    path = Path(directory) / f"{template.name}{SUFFIX}"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp, old = path.with_name(f".{path.name}.partial"), path.with_name(f".{path.name}.old")
    for leftover in (tmp, old):
        shutil.rmtree(leftover, ignore_errors=True)
    tmp.mkdir()
    try:
        _write_template(template, tmp)
        if path.exists():
            os.rename(path, old)
        os.rename(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
    return path


def _write_template(template: Template, path: Path) -> None:
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "kind": template.kind,
        "name": template.name,
        "T_base_tcp_photo": np.asarray(template.T_base_tcp_photo).tolist(),
        "preprocess": template.preprocess,
        "frame": None if template.frame is None else template.frame.to_dict(),
        "metadata": template.metadata,
    }
    if template.points is not None:
        pts = np.ascontiguousarray(template.points, dtype=np.float64)
        np.save(path / "points.npy", pts, allow_pickle=False)
        doc.update(
            points_file="points.npy",
            points_sha256=hashlib.sha256((path / "points.npy").read_bytes()).hexdigest(),
            n_points=int(pts.shape[0]),
            points_resolution=template.points_resolution,
        )
    (path / "template.json").write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")


def load_template(path: str | Path) -> Template:
    """Read a template directory written by :func:`save_template`; raises InvalidInputError with a reason."""
    path = Path(path)
    meta_file = path / "template.json"
    if not path.exists():
        raise InvalidInputError(f"no template at {path} (make one with `vgr template make`)")
    if not path.is_dir():
        raise InvalidInputError(f"{path} is a file; a vgr template is a folder (template.json and its cloud)")
    if not meta_file.is_file():
        raise InvalidInputError(f"{path} is not a vgr template (no template.json)")
    try:
        doc = json.loads(meta_file.read_text())
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"{meta_file}: not valid JSON ({exc})") from exc
    if doc.get("schema") != SCHEMA:
        raise InvalidInputError(f"{meta_file}: schema {doc.get('schema')!r} is not {SCHEMA!r}")
    version = doc.get("schema_version")
    if not isinstance(version, int) or version < 1 or version > SCHEMA_VERSION:
        raise InvalidInputError(
            f"{meta_file}: schema_version {version!r} not supported (this vgr reads <= {SCHEMA_VERSION})"
        )
    try:
        T_photo = tf.as_transform(doc["T_base_tcp_photo"], name="T_base_tcp_photo", tol=1e-5)
    except (KeyError, ValueError) as exc:
        raise InvalidInputError(f"{meta_file}: bad T_base_tcp_photo ({exc})") from exc
    kind = doc.get("kind")
    resolution = "voxel" if version < 2 else doc.get("points_resolution", "full")
    if resolution not in ("full", "voxel"):
        raise InvalidInputError(f"{meta_file}: points_resolution {resolution!r} is not 'full' or 'voxel'")
    points = frame = None
    if kind == "cloud":
        pfile = path / str(doc.get("points_file", "points.npy"))
        if not pfile.is_file():
            raise InvalidInputError(f"{path}: cloud template without its points file {pfile.name}")
        digest = hashlib.sha256(pfile.read_bytes()).hexdigest()
        if digest != doc.get("points_sha256"):
            raise InvalidInputError(f"{pfile}: checksum mismatch (file changed after the template was made)")
        points = np.load(pfile, allow_pickle=False)
        if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
            raise InvalidInputError(f"{pfile}: expected finite (N, 3) points, got {points.shape}")
    elif kind == "feature_frame":
        if not doc.get("frame"):
            raise InvalidInputError(f"{meta_file}: feature_frame template without a frame")
        frame = FeatureFrame.from_dict(doc["frame"])
    else:
        raise InvalidInputError(f"{meta_file}: unknown template kind {kind!r}")
    return Template(
        kind=kind,
        name=str(doc["name"]),
        T_base_tcp_photo=T_photo,
        preprocess=dict(doc.get("preprocess") or {}),
        points=points,
        frame=frame,
        metadata=dict(doc.get("metadata") or {}),
        schema_version=version,
        points_resolution=resolution,
    )


def roi_from_dict(d: dict[str, Any] | None) -> RoiBox | None:
    """Inverse of :meth:`RoiBox.to_dict` (for re-using a template's ROI on the current captures)."""
    if d is None:
        return None
    return RoiBox(center=tuple(d["center"]), extent=tuple(d["extent"]), rotation=tuple(tuple(r) for r in d["rotation"]))
