"""Feature-frame matcher (seed 000 method B): main plane + two circular features -> workpiece frame,
``T_match = Frame_template @ inv(Frame_current)``.

The frame (pose of the workpiece frame in the camera frame, ``T_cam_frame``): origin at the centre
of feature 1 on the plane, Z = plane normal oriented towards the camera (``viewpoint``), X = from
feature 1 to feature 2 projected into the plane, Y = Z x X.

Which detected feature is "1": when a reference (template) frame is given, the ordered pair whose
spacing, radii and plane-centroid position (in frame coordinates) best match the reference is used;
the plane centroid is what tells the two orderings of two equal features apart, so a part that is
symmetric about its feature pair is reported ``ambiguous``. Without a reference (template making),
features are ordered by radius, then by their coordinate along the plane's first basis vector.

Uncertainty is first-order: centre sigma = rim RMS * sqrt(2 / n_rim) per circle, plane offset sigma
= plane RMS / sqrt(N), tilt sigma = plane RMS / (sqrt(N) * RMS radius of the plane points), spin
sigma about Z = hypot(centre sigmas) / feature spacing; template and current variances add.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple

import numpy as np

from engine import transforms as tf
from plugins.registration.circles import Circle, find_holes, find_pins
from plugins.registration.plane import PlaneFit, plane_basis, segment_main_plane
from plugins.registration.preprocess import PreprocessParams, prepare_cloud
from plugins.registration.result import RegistrationResult, failed
from plugins.registration.validation import InvalidInputError


@dataclass(frozen=True)
class FeatureFrameParams:
    """Feature-frame settings (metres).

    ``feature_kind``: ``hole`` or ``pin``. ``radius_m``: nominal feature radius (None: accept
    ``min_radius_m``..``max_radius_m``); with a nominal radius, circles within ``radius_tolerance_m``
    are accepted. ``plane_distance_m``: plane inlier band (default 2x the point spacing, >= 0.3 mm).
    ``preprocess``: a fine voxel (0.5 mm default) keeps rim detail while bounding the point count.
    ``max_spacing_mismatch_m`` / ``max_radius_mismatch_m``: beyond these the current features are not
    the template's (wrong part). ``order_margin_m``: minimum plane-centroid discrepancy between the
    two feature orderings for the order to count as determined.
    """

    feature_kind: Literal["hole", "pin"] = "hole"
    radius_m: float | None = None
    radius_tolerance_m: float = 0.75e-3
    min_radius_m: float = 1.0e-3
    max_radius_m: float = 0.02
    plane_distance_m: float | None = None
    plane_iterations: int = 1000
    pin_min_height_m: float = 2.0e-3
    pin_max_height_m: float = 0.05
    preprocess: PreprocessParams = field(default_factory=lambda: PreprocessParams(voxel_size_m=0.5e-3))
    max_spacing_mismatch_m: float = 1.0e-3
    max_radius_mismatch_m: float = 0.75e-3
    order_margin_m: float = 3.0e-3
    seed: int = 0


@dataclass
class FeatureFrame:
    """A fitted workpiece frame and what it was built from (camera frame, metres)."""

    T_cam_frame: np.ndarray
    centers: np.ndarray  # (2, 3) feature centres on the plane, feature 1 first
    radii: np.ndarray  # (2,)
    circle_rms_m: np.ndarray  # (2,)
    n_rim: np.ndarray  # (2,)
    plane_rms_m: float
    n_plane: int
    plane_radius_m: float
    plane_centroid_in_frame: np.ndarray  # (3,)
    kind: str
    n_candidates: int = 2

    @property
    def spacing_m(self) -> float:
        return float(np.linalg.norm(self.centers[1] - self.centers[0]))

    def sigmas(self) -> np.ndarray:
        """First-order one-sigma (x, y, z, rx, ry, rz) in the frame's own axes at its origin."""
        c = self.circle_rms_m * np.sqrt(2.0 / np.maximum(self.n_rim, 1))
        z = self.plane_rms_m / np.sqrt(max(self.n_plane, 1))
        tilt = z / max(self.plane_radius_m, 1e-9)
        spin = float(np.hypot(c[0], c[1]) / max(self.spacing_m, 1e-9))
        return np.array([c[0], c[0], z, tilt, tilt, spin])

    def to_dict(self) -> dict[str, Any]:
        return {
            "T_cam_frame": self.T_cam_frame.tolist(),
            "centers": self.centers.tolist(),
            "radii": self.radii.tolist(),
            "circle_rms_m": self.circle_rms_m.tolist(),
            "n_rim": self.n_rim.tolist(),
            "plane_rms_m": self.plane_rms_m,
            "n_plane": self.n_plane,
            "plane_radius_m": self.plane_radius_m,
            "plane_centroid_in_frame": self.plane_centroid_in_frame.tolist(),
            "kind": self.kind,
            "n_candidates": self.n_candidates,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FeatureFrame:
        return cls(
            T_cam_frame=np.asarray(d["T_cam_frame"], dtype=float),
            centers=np.asarray(d["centers"], dtype=float),
            radii=np.asarray(d["radii"], dtype=float),
            circle_rms_m=np.asarray(d["circle_rms_m"], dtype=float),
            n_rim=np.asarray(d["n_rim"], dtype=np.int64),
            plane_rms_m=float(d["plane_rms_m"]),
            n_plane=int(d["n_plane"]),
            plane_radius_m=float(d["plane_radius_m"]),
            plane_centroid_in_frame=np.asarray(d["plane_centroid_in_frame"], dtype=float),
            kind=str(d["kind"]),
            n_candidates=int(d.get("n_candidates", 2)),
        )


class AmbiguousOrderError(InvalidInputError):
    """Both orderings of the feature pair explain the data equally well."""


class _Features(NamedTuple):
    """The main plane of a cloud (normal ``n`` oriented towards the camera, inlier points
    ``plane_pts``, RMS radius about the normal) and the circular features found on it, with their
    centres on the plane (camera frame)."""

    plane: PlaneFit
    n: np.ndarray
    plane_pts: np.ndarray
    plane_radius: float
    circles: list[Circle]
    centers3: np.ndarray


def _frame(c1: np.ndarray, c2: np.ndarray, n: np.ndarray) -> np.ndarray:
    x = (c2 - c1) - ((c2 - c1) @ n) * n
    x /= np.linalg.norm(x)
    return tf.T_from_Rt(np.column_stack([x, np.cross(n, x), n]), c1)


def _find_circles(
    pts: np.ndarray,
    plane_pts: np.ndarray,
    o: np.ndarray,
    n: np.ndarray,
    B: np.ndarray,
    spacing: float,
    params: FeatureFrameParams,
) -> list[Circle]:
    """Holes in the plane points, or pins standing on the plane (origin *o*, normal *n*, basis *B*),
    within the accepted radii; raises InvalidInputError when fewer than two are found."""
    if params.radius_m is not None:
        r_lo, r_hi = params.radius_m - params.radius_tolerance_m, params.radius_m + params.radius_tolerance_m
    else:
        r_lo, r_hi = params.min_radius_m, params.max_radius_m
    circles: list[Circle]
    if params.feature_kind == "hole":
        circles = find_holes((plane_pts - o) @ B, spacing_m=spacing, min_radius_m=r_lo, max_radius_m=r_hi)
    else:
        circles = find_pins(
            pts - o,
            (pts - o) @ n,
            B,
            spacing_m=spacing,
            min_height_m=params.pin_min_height_m,
            max_height_m=params.pin_max_height_m,
            min_radius_m=r_lo,
            max_radius_m=r_hi,
        )
    if len(circles) < 2:
        raise InvalidInputError(
            f"found {len(circles)} circular {params.feature_kind}(s) with radius "
            f"{r_lo * 1e3:.3g}-{r_hi * 1e3:.3g} mm on the main plane; need 2"
        )
    return circles


def _detect_features(cloud: Any, params: FeatureFrameParams, name: str) -> _Features:
    """Prepare *cloud*, segment its main plane (normal towards ``viewpoint``) and find the circular
    features on it; raises InvalidInputError with a reason."""
    prep = prepare_cloud(cloud, params.preprocess, name=name)
    pts = prep.points
    spacing = prep.spacing()
    dist = params.plane_distance_m or max(2.0 * spacing, 0.3e-3)
    plane = segment_main_plane(pts, distance_m=dist, iterations=params.plane_iterations, seed=params.seed)
    n = plane.normal
    if prep.viewpoint is not None and (np.asarray(prep.viewpoint) - plane.centroid) @ n < 0:
        n = -n
    B = plane_basis(n)
    o = plane.centroid
    plane_pts = pts[plane.inliers]
    circles = _find_circles(pts, plane_pts, o, n, B, spacing, params)
    centers3 = np.array([o + B @ c.center_uv for c in circles])
    rel = plane_pts - o
    plane_radius = float(np.sqrt(np.mean(np.sum((rel - np.outer(rel @ n, n)) ** 2, axis=1))))
    return _Features(plane, n, plane_pts, plane_radius, circles, centers3)


def _candidate(f: _Features, i: int, j: int, kind: str) -> FeatureFrame:
    """The frame with feature *i* as feature 1 and feature *j* as feature 2."""
    T = _frame(f.centers3[i], f.centers3[j], f.n)
    cen = tf.transform_points(tf.inv(T), f.plane_pts.mean(axis=0)[None, :])[0]
    circles = f.circles
    return FeatureFrame(
        T_cam_frame=T,
        centers=f.centers3[[i, j]],
        radii=np.array([circles[i].radius_m, circles[j].radius_m]),
        circle_rms_m=np.array([circles[i].rms_m, circles[j].rms_m]),
        n_rim=np.array([circles[i].n_rim, circles[j].n_rim]),
        plane_rms_m=f.plane.rms_m,
        n_plane=int(f.plane.inliers.size),
        plane_radius_m=f.plane_radius,
        plane_centroid_in_frame=cen,
        kind=kind,
        n_candidates=len(circles),
    )


def _frame_without_reference(f: _Features, kind: str) -> FeatureFrame:
    """Template making: features ordered by radius, then by their coordinate along the plane's first
    basis vector; of more than two, the farthest-apart pair (kept in that order)."""
    circles, centers3 = f.circles, f.centers3
    order = sorted(range(len(circles)), key=lambda k: (round(circles[k].radius_m / 1e-4), circles[k].center_uv[0]))
    if len(circles) > 2:  # the farthest-apart pair is the most precise X axis
        pairs = itertools.combinations(range(len(circles)), 2)
        i, j = max(pairs, key=lambda p: np.linalg.norm(centers3[p[0]] - centers3[p[1]]))
        order = sorted((i, j), key=lambda k: order.index(k))
    return _candidate(f, order[0], order[1], kind)


def _reference_cost(ff: FeatureFrame, reference: FeatureFrame) -> tuple[float, float]:
    """(geometry mismatch: spacing + worst radius, plane-centroid cue) of a candidate against *reference*."""
    geom = abs(ff.spacing_m - reference.spacing_m) + float(np.max(np.abs(ff.radii - reference.radii)))
    cue = float(np.linalg.norm(ff.plane_centroid_in_frame[:2] - reference.plane_centroid_in_frame[:2]))
    return geom, cue


def _frame_against_reference(f: _Features, reference: FeatureFrame, params: FeatureFrameParams) -> FeatureFrame:
    """The ordered pair that best matches *reference*: among the pairs that match its geometry, the
    best plane-centroid cue; AmbiguousOrderError when the same pair swapped is within
    ``order_margin_m`` of it."""
    options = [_candidate(f, i, j, params.feature_kind) for i, j in itertools.permutations(range(len(f.circles)), 2)]
    costs = [_reference_cost(o, reference) for o in options]
    best_geom = min(c[0] for c in costs)
    # among pairs that match the template's geometry, order by the plane-centroid cue
    viable = sorted(
        (k for k, c in enumerate(costs) if c[0] <= best_geom + params.max_spacing_mismatch_m),
        key=lambda k: costs[k][1],
    )
    best = options[viable[0]]
    for k in viable[1:]:
        other = options[k]
        if np.allclose(other.centers[0], best.centers[1]) and np.allclose(other.centers[1], best.centers[0]):
            margin = costs[k][1] - costs[viable[0]][1]
            if margin < params.order_margin_m:
                raise AmbiguousOrderError(
                    "the two features cannot be told apart: the part looks the same with them swapped "
                    f"(plane-centroid cue differs by {margin * 1e3:.2g} mm < "
                    f"{params.order_margin_m * 1e3:.3g} mm)"
                )
            break
    return best


def fit_feature_frame(
    cloud: Any,
    params: FeatureFrameParams | None = None,
    *,
    reference: FeatureFrame | None = None,
    name: str = "cloud",
) -> FeatureFrame:
    """Fit the workpiece frame of *cloud* (see module docstring); raises InvalidInputError with a reason
    (AmbiguousOrderError when the feature order cannot be decided against *reference*)."""
    params = params or FeatureFrameParams()
    features = _detect_features(cloud, params, name)
    if reference is None:
        return _frame_without_reference(features, params.feature_kind)
    return _frame_against_reference(features, reference, params)


def register_feature_frame(
    current: Any,
    template: FeatureFrame | Any,
    params: FeatureFrameParams | None = None,
) -> RegistrationResult:
    """``T_match = Frame_template @ inv(Frame_current)`` (maps current points onto the template).

    *template* is a :class:`FeatureFrame` (from a stored template) or a cloud to fit one from.
    Never raises on bad input: the result is ``failed`` (or ``ambiguous``) with the reason.
    """
    params = params or FeatureFrameParams()
    method = f"feature_frame:{params.feature_kind}"
    t0 = time.perf_counter()
    try:
        F_t = template if isinstance(template, FeatureFrame) else fit_feature_frame(template, params, name="template")
    except InvalidInputError as exc:
        return failed(method, str(exc))
    except Exception as exc:  # a fitting error must not escape the stage
        return failed(method, f"template: {type(exc).__name__}: {exc}")
    try:
        F_c = fit_feature_frame(current, params, reference=F_t, name="current")
    except AmbiguousOrderError as exc:
        res = RegistrationResult(verdict="ambiguous", method=method, reasons=[f"current: {exc}"])
        res.details["template_frame"] = F_t.to_dict()
        return res
    except InvalidInputError as exc:
        return failed(method, str(exc) if str(exc).startswith("current") else f"current: {exc}")
    except Exception as exc:  # a fitting error must not escape the stage
        return failed(method, f"current: {type(exc).__name__}: {exc}")

    T_match = F_t.T_cam_frame @ tf.inv(F_c.T_cam_frame)
    d_spacing = abs(F_c.spacing_m - F_t.spacing_m)
    d_radius = float(np.max(np.abs(F_c.radii - F_t.radii)))
    details: dict[str, Any] = {
        "template_frame": F_t.to_dict(),
        "current_frame": F_c.to_dict(),
        "spacing_mismatch_m": d_spacing,
        "radius_mismatch_m": d_radius,
        "plane_rms_m": [F_t.plane_rms_m, F_c.plane_rms_m],
        "circle_rms_m": [F_t.circle_rms_m.tolist(), F_c.circle_rms_m.tolist()],
    }
    reasons = []
    if d_spacing > params.max_spacing_mismatch_m:
        reasons.append(
            f"feature spacing {F_c.spacing_m * 1e3:.3f} mm differs from the template's "
            f"{F_t.spacing_m * 1e3:.3f} mm by more than {params.max_spacing_mismatch_m * 1e3:.3g} mm: "
            "wrong part?"
        )
    if d_radius > params.max_radius_mismatch_m:
        reasons.append(
            f"feature radii differ from the template's by {d_radius * 1e3:.3f} mm "
            f"(> {params.max_radius_mismatch_m * 1e3:.3g} mm): wrong part?"
        )
    if reasons:
        res = failed(method, *reasons, **details)
        res.details["T_candidate"] = T_match
        return res

    # per-axis sigma: frame-axis variances of both fits, rotated into the template camera axes
    var = F_t.sigmas() ** 2 + F_c.sigmas() ** 2
    R = F_t.T_cam_frame[:3, :3]
    cov_c = np.zeros((6, 6))
    cov_c[:3, :3] = R @ np.diag(var[:3]) @ R.T
    cov_c[3:, 3:] = R @ np.diag(var[3:]) @ R.T
    Ad = tf.adjoint(tf.T_from_Rt(np.eye(3), F_t.centers[0]))
    res = RegistrationResult(
        verdict="ok",
        method=method,
        T_match=T_match,
        fitness=1.0,
        inlier_rmse=float(np.sqrt(np.mean(np.concatenate([F_t.circle_rms_m, F_c.circle_rms_m]) ** 2))),
        covariance=Ad @ cov_c @ Ad.T,
        uncertainty_center=F_t.centers[0].copy(),
        sigma_translation_m=np.sqrt(np.diag(cov_c)[:3]),
        sigma_rotation_rad=np.sqrt(np.diag(cov_c)[3:]),
        converged=True,
        details=details,
    )
    res.timings_s = {"total": time.perf_counter() - t0}
    return res
