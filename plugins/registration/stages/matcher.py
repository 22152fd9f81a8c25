"""``matcher``: the point-cloud matchers as a solver stage with ``match`` services.

The stage loads a template (made by ``vgr template make``) at set-up and answers requests with a
PointCloud (the current capture, camera frame) in and a :class:`MatchResult` out:

* ``match_first`` uses ``first_method`` (global registration by default): the first look at a part
  that may be far off;
* ``match`` uses ``method`` (fine ICP from identity by default): later looks, after the robot has
  compensated the previous estimate.

The template is prepared once at set-up (voxel grids, normals, k-d trees, contour edges stay cached).
The defaults serve both seed 000's feature-rich parts and seed 004's planar plate seen from above
against a captured template: a plate's in-plane pose is then taken from its contour (``edges``
auto; measured 12/12 first looks within 0.5 mm / 0.5 deg, tests/registration/
test_registration_stage.py). ``coarse_backend`` refines the global hypotheses; ``open3d_plane``
(for ``backend`` and ``coarse_backend``) suits a CAD-model template of a plate, not a captured one.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from engine.messages import PointCloud
from engine.stage import ServiceSpec, Stage, StageParams, input_file
from plugins.registration.edges import EdgeParams
from plugins.registration.feature_frame import FeatureFrameParams, register_feature_frame
from plugins.registration.fine import FineParams, register_fine
from plugins.registration.fine_backends import Backend
from plugins.registration.global_registration import GlobalParams, register_global
from plugins.registration.messages import MatchResult
from plugins.registration.preprocess import PreprocessParams, RoiBox
from plugins.registration.result import failed
from plugins.registration.template import Template, load_template

Method = Literal["fine", "global", "feature_frame"]
MATCH_SERVICE = ServiceSpec(PointCloud, MatchResult, "match a capture against the template (method)")
MATCH_FIRST_SERVICE = ServiceSpec(PointCloud, MatchResult, "first look at a part (first_method)")


class Matcher(Stage):
    """Matches captures against a template: fine ICP, global + planar correction, or feature frame."""

    type_name = "matcher"
    role = "solver"
    services: ClassVar = {"match": MATCH_SERVICE, "match_first": MATCH_FIRST_SERVICE}

    class Params(StageParams):
        template: str = input_file(description="template directory (.vgrtpl); relative paths: to the recipe file")
        method: Method = Field("fine", description="matcher for later looks (after a correction)")
        first_method: Method = Field("global", description="matcher for the first look at a part")
        backend: Backend = Field("small_gicp_gicp", description="fine backend (see docs/registration.md)")
        voxel_size_m: float = Field(0.002, gt=0.0, le=0.05)
        polish_voxel_m: float | None = Field(0.0, ge=0.0, description="final pass at this voxel; 0 = all points")
        polish_step_um: float = Field(
            1.0,
            gt=0.0,
            description="the polish stops once an iteration moves the part by less than this (um) and turns "
            "it by less than this over 0.1 m (far below any capture's noise; at the fine stage's 0.1 um "
            "small_gicp often ran to its iteration limit)",
        )
        roi_min_m: tuple[float, float, float] | None = Field(None, description="crop box of the capture (camera frame)")
        roi_max_m: tuple[float, float, float] | None = None
        min_fitness: float = Field(0.5, gt=0.0, le=1.0)
        max_sigma_translation_mm: float = Field(0.2, gt=0.0)
        max_sigma_rotation_deg: float = Field(0.2, gt=0.0)
        global_method: Literal["auto", "planar", "fpfh"] = "auto"
        coarse_backend: Backend = Field(
            "small_gicp_gicp", description="ICP backend that refines the global hypotheses on the coarse clouds"
        )
        edges: Literal["auto", "on", "off"] = Field(
            "auto", description="contour edge term for weak geometry (a plate seen from above); see docs"
        )
        ambiguity_gap: float = Field(0.1, ge=0.0, le=1.0)
        feature_kind: Literal["hole", "pin"] = "hole"
        feature_radius_m: float | None = None
        threads: int = Field(
            1,
            ge=1,
            le=64,
            description="threads for per-point work (k-d trees, normals, FPFH, queries); results are "
            "bit-identical at any value (ICP iterations always run on one thread; see docs)",
        )

    def setup(self) -> None:
        p: Matcher.Params = self.params  # type: ignore[assignment]
        path = self.ctx.input_path(p.template)
        self.template: Template = load_template(path)
        if self.template.points is not None:
            self.template.prepared()  # built once here, reused (with its caches) by every match
        roi = RoiBox.from_bounds(p.roi_min_m, p.roi_max_m) if p.roi_min_m and p.roi_max_m else None
        pre = PreprocessParams(voxel_size_m=p.voxel_size_m, roi=roi)
        self.fine = FineParams(
            backend=p.backend,
            preprocess=pre,
            num_threads=p.threads,
            min_fitness=p.min_fitness,
            max_sigma_translation_m=p.max_sigma_translation_mm / 1e3,
            max_sigma_rotation_rad=float(np.radians(p.max_sigma_rotation_deg)),
            polish_voxel_m=p.polish_voxel_m,
            polish_translation_eps_m=p.polish_step_um * 1e-6,
            polish_rotation_eps_rad=p.polish_step_um * 1e-5,
            edges=EdgeParams(mode=p.edges),
        )
        self.global_ = GlobalParams(
            method=p.global_method,
            fine=self.fine,
            coarse_backend=p.coarse_backend,
            ambiguity_gap=p.ambiguity_gap,
            seed=self.ctx.seed & 0x7FFFFFFF,
        )
        self.feature = replace(
            FeatureFrameParams(),
            feature_kind=p.feature_kind,
            radius_m=p.feature_radius_m,
            seed=self.ctx.seed & 0x7FFFFFFF,
        )

    def match(self, cloud: PointCloud, method: Method) -> MatchResult:
        tpl = self.template
        try:
            if method == "feature_frame":
                target: Any = tpl.frame if tpl.frame is not None else tpl.prepared()
                res = register_feature_frame(cloud.points, target, self.feature)
            elif tpl.points is None:
                res = failed(method, f"template {tpl.name!r} is a {tpl.kind} template: use method feature_frame")
            elif method == "global":
                res = register_global(cloud.points, tpl.prepared(), self.global_)
            else:
                res = register_fine(cloud.points, tpl.prepared(), None, self.fine)
        except Exception as exc:  # the library promises failed results, but a stage must never crash on data
            res = failed(method, f"{type(exc).__name__}: {exc}")
        return MatchResult.from_result(res, frame_id=cloud.frame_id or "camera")

    def on_request(self, service: str, request: PointCloud) -> MatchResult:  # type: ignore[override]
        p: Matcher.Params = self.params  # type: ignore[assignment]
        return self.match(request, p.first_method if service == "match_first" else p.method)
