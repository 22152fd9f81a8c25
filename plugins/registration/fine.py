"""Fine registration (seed 000 method A): ``T_match = ICP(P_current, P_template)`` from an initial guess,
with a selectable backend, one scoring rule, the Hessian-based uncertainty and a verdict.

``p_template = T_match @ p_current`` (source = current, target = template); see ``result.py``.

Defaults are sized for workpieces seen by a structured-light/ToF camera at 0.3-1 m: 2 mm voxels,
correspondences up to 5x the cloud resolution, convergence at 1e-7 m / 1e-6 rad (LiDAR defaults such
as small_gicp's 1 mm / 0.1 deg would stop far above the 0.02 mm this stage must reach).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from engine import transforms as tf
from plugins.registration.edges import (
    EdgeParams,
    EdgeSet,
    away_from_edges,
    detect_edges,
    edge_icp,
    edge_pairs,
    edge_set,
)
from plugins.registration.fine_backends import BACKENDS, IcpSettings, run_backend
from plugins.registration.preprocess import PreparedCloud, PreprocessParams, prepare_cloud
from plugins.registration.result import RegistrationResult, failed
from plugins.registration.scoring import AlignmentScore, score_alignment
from plugins.registration.uncertainty import PoseUncertainty, pose_uncertainty
from plugins.registration.validation import InvalidInputError, as_initial_transform


@dataclass(frozen=True)
class FineParams:
    """Fine-registration settings (metres, radians).

    Distances left at None scale with the template's resolution ``res`` (max of voxel size and point
    spacing): correspondences up to ``5 res``, inliers within ``1.5 res``, score truncated at ``3 res``.

    ``polish_voxel_m`` (None = off; 0 = every point): after converging on the downsampled clouds, run
    the backend once more on the clouds at this voxel size with correspondences up to
    ``polish_correspondence_m`` (default: the main voxel size; at most ``polish_max_iterations``, it
    starts converged: 1-5 iterations measured, but small_gicp can oscillate below the noise on
    240k points for all 64 at 0.3 s each) and evaluate there. Downsampling to
    2 mm averages the noise but also discards information: on a 0.1 mm-noise capture the rotation
    about the optical axis is only determined to ~0.01 deg at 2 mm, ~0.002 deg at full resolution.

    Verdict rules: ``failed`` when fitness < ``min_fitness`` or inliers < ``min_inliers`` or the
    estimate did not converge (the backend reports hitting its iteration limit and a re-run of
    ``recheck_iterations`` from the estimate still moves the part centre by more than
    ``10 * translation_eps_m`` or rotates it by more than ``10 * rotation_eps_rad``; small_gicp
    can stop at its limit while oscillating far below the noise, which is accepted);
    ``ambiguous`` when a per-axis one-sigma at the part centre exceeds ``max_sigma_translation_m`` /
    ``max_sigma_rotation_rad``, or a stiffness ratio is below ``degenerate_ratio`` (a direction the
    geometry does not determine); weak directions (stiffness ratio < ``weak_ratio``) are always listed.

    ``edges`` (see edges.py): with ``mode="auto"`` (default), when the template's surfaces leave a
    weak direction (:func:`template_stiffness`; a plate seen from above), the estimate is refined
    with the contour's edge points (point-to-plane + edge rows) instead of the polish and evaluated
    with them; ``failed`` if less than ``edges.min_fitness`` of the current edge points then match
    the template's.

    Uncertainty (see uncertainty.py): cluster-robust over cubes of ``sigma_cluster_factor``
    template resolutions (0 = the i.i.d. formula), every sigma times ``sigma_scale`` (2.0: measured
    on simulated captures, checked on held-out ones). The ``max_sigma_*`` limits apply to these.
    """

    backend: str = "small_gicp_gicp"
    preprocess: PreprocessParams = field(default_factory=PreprocessParams)
    max_correspondence_m: float | None = None
    max_iterations: int = 64
    rotation_eps_rad: float = 1e-6
    translation_eps_m: float = 1e-7
    num_threads: int = 1
    inlier_distance_m: float | None = None
    truncation_m: float | None = None
    min_fitness: float = 0.5
    min_inliers: int = 30
    weak_ratio: float = 1e-3
    degenerate_ratio: float = 1e-6
    max_sigma_translation_m: float = 0.2e-3
    max_sigma_rotation_rad: float = float(np.radians(0.2))
    kiss_voxel_m: float | None = None
    kiss_points_per_voxel: int = 20
    polish_voxel_m: float | None = None
    polish_correspondence_m: float | None = None
    polish_backend: str | None = None
    polish_max_iterations: int = 20
    polish_translation_eps_m: float | None = None  # the polish's step tolerances (None: the fine stage's)
    polish_rotation_eps_rad: float | None = None
    recheck_iterations: int = 10
    edges: EdgeParams = field(default_factory=EdgeParams)
    sigma_cluster_factor: float = 5.0
    sigma_scale: float = 2.0

    def distances(self, template: PreparedCloud) -> tuple[float, float, float]:
        """(max correspondence, inlier distance, truncation) in metres for this template."""
        res = template.resolution()
        return (
            self.max_correspondence_m or 5.0 * res,
            self.inlier_distance_m or 1.5 * res,
            self.truncation_m or 3.0 * res,
        )


class _EdgeTerm(NamedTuple):
    """The contour's part in an evaluation: edge rows ``(p, q, m)`` for the Hessian (None without
    edges), their residual-variance floor, and whether the contour match refutes the pose."""

    rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    floor: float = 0.0
    refutes: bool = False


def percents(have: float, need: float) -> tuple[str, str]:
    """*have* and *need* as percentages with as few decimals as tell them apart (at most 4): not
    "only 100 % ... (need 100 %)" for 99.996 % against 99.999 %."""
    for decimals in range(5):
        shown = f"{have:.{decimals}%}", f"{need:.{decimals}%}"
        if shown[0] != shown[1]:
            break
    return shown


def _overlap_reasons(sc: AlignmentScore, inlier_d: float, params: FineParams) -> list[str]:
    """Why the overlap is too small for a match (too few inliers, or too low a fitness); [] if enough."""
    if sc.n_inliers < max(params.min_inliers, 7):
        return [
            f"only {sc.n_inliers} current points lie within {inlier_d * 1e3:.3g} mm of the template "
            f"(need {params.min_inliers}): wrong part, part missing or initial guess too far"
        ]
    if sc.fitness < params.min_fitness:
        have, need = percents(sc.fitness, params.min_fitness)
        return [
            f"only {have} of the current points lie within {inlier_d * 1e3:.3g} mm of the "
            f"template (need {need}): wrong part, part missing or initial guess too far"
        ]
    return []


def _refuse(res: RegistrationResult, reasons: list[str], T_match: np.ndarray, failure: str) -> RegistrationResult:
    """Mark *res* ``failed`` for *reasons*, keeping *T_match* as the candidate; ``failure`` says why."""
    res.verdict = "failed"
    res.reasons = reasons
    res.details["T_candidate"] = T_match
    res.details["failure"] = failure
    return res


def _contour_check(
    res: RegistrationResult, reasons: list[str], edges: tuple[EdgeSet, EdgeSet], T_match: np.ndarray, ep: EdgeParams
) -> _EdgeTerm:
    """Match the current contour onto the template's at *T_match*: records the edge fitness, adds a
    reason when too little of it matches, and returns the edge rows for the Hessian."""
    spacing = max(edges[0].spacing, edges[1].spacing)
    pairs = edge_pairs(edges[0], edges[1], T_match, ep.inlier_factor * spacing, ep.min_cos)
    res.details["edge_fitness"] = pairs.fitness
    res.details["edge_points"] = len(edges[0])
    contour_refutes = bool(pairs.fitness < ep.min_fitness)
    if contour_refutes:
        have, need = percents(pairs.fitness, ep.min_fitness)
        reasons.append(
            f"only {have} of the current contour ({len(edges[0])} edge points) lies within "
            f"{ep.inlier_factor * spacing * 1e3:.2g} mm of the template's (need {need}): "
            "wrong pose (e.g. turned in the plane) or wrong part"
        )
    edge_floor = spacing**2 / 6.0  # each capture's contour is sampled to +-spacing / 2
    return _EdgeTerm((pairs.p, pairs.q, pairs.m), edge_floor, contour_refutes)


def _match_uncertainty(
    current: PreparedCloud,
    template: PreparedCloud,
    T_match: np.ndarray,
    sc: AlignmentScore,
    params: FineParams,
    edges: tuple[EdgeSet, EdgeSet] | None,
    edge_term: _EdgeTerm,
) -> PoseUncertainty:
    """Pose uncertainty from the inlier pairs of *sc* (without the surface rows at the template's
    contour when the edge rows are used) plus the edge rows."""
    src, tgt = sc.inlier_source, sc.inlier_target
    if edges is not None:  # at the contour the edge rows replace the surface rows (edges.away_from_edges)
        keep = away_from_edges(template, edges[1])[tgt]
        src, tgt = src[keep], tgt[keep]
    p = tf.transform_points(T_match, current.points[src])
    q = template.points[tgt]
    n = template.normals()[tgt]
    return pose_uncertainty(
        p,
        q,
        n,
        weak_ratio=params.weak_ratio,
        edges=edge_term.rows,
        edge_variance_floor=edge_term.floor,
        cluster_size_m=params.sigma_cluster_factor * template.resolution() if params.sigma_cluster_factor else None,
        scale=params.sigma_scale,
    )


def _sigma_excess(unc: PoseUncertainty, params: FineParams) -> str | None:
    """The reason when a per-axis one-sigma exceeds ``max_sigma_*``; None within the limits."""
    over_t = unc.sigma_translation_m > params.max_sigma_translation_m
    over_r = unc.sigma_rotation_rad > params.max_sigma_rotation_rad
    if not (np.any(over_t) or np.any(over_r)):
        return None
    axes = [f"{a} {s * 1e3:.3g} mm" for a, s, o in zip("xyz", unc.sigma_translation_m, over_t, strict=True) if o]
    axes += [
        f"r{a} {np.degrees(s):.3g} deg" for a, s, o in zip("xyz", unc.sigma_rotation_rad, over_r, strict=True) if o
    ]
    return (
        "pose not determined by the geometry: 1-sigma "
        + ", ".join(axes)
        + f" exceeds the limits ({params.max_sigma_translation_m * 1e3:.3g} mm, "
        f"{np.degrees(params.max_sigma_rotation_rad):.3g} deg)"
    )


def _uncertainty_verdict(
    res: RegistrationResult, unc: PoseUncertainty, T_match: np.ndarray, params: FineParams
) -> RegistrationResult:
    """Attach the uncertainty to *res* (its reasons become the weak directions) and decide the verdict
    from it: ``ambiguous`` for a degenerate direction or a sigma over the limits, ``failed`` for a
    non-finite uncertainty, else ``ok`` with *T_match*."""
    res.details["stationarity_chi2"] = unc.stationarity_chi2
    res.hessian = unc.hessian
    res.covariance = unc.covariance
    res.uncertainty_center = unc.center
    res.sigma_translation_m = unc.sigma_translation_m
    res.sigma_rotation_rad = unc.sigma_rotation_rad
    res.weak_directions = unc.weak_directions
    res.details["residual_sigma_m"] = unc.residual_sigma_m
    res.details["stiffness_ratios"] = unc.eigen_ratios
    res.reasons = [w.describe() for w in unc.weak_directions]
    degenerate = [w for w in unc.weak_directions if w.ratio < params.degenerate_ratio]
    if degenerate:  # also when the residuals are all zero and every sigma reads 0
        res.verdict = "ambiguous"
        res.reasons.insert(
            0,
            f"pose not determined by the geometry: {len(degenerate)} direction(s) with stiffness ratio "
            f"< {params.degenerate_ratio:.0e} (e.g. a plane that can slide or spin)",
        )
        res.details["T_candidate"] = T_match
        return res
    if not (
        np.all(np.isfinite(unc.sigma_translation_m))
        and np.all(np.isfinite(unc.sigma_rotation_rad))
        and np.all(np.isfinite(unc.covariance))
    ):  # (a NaN sigma would pass every "> limit" test below: no verdict from an unknown uncertainty)
        res.verdict = "failed"
        res.reasons.insert(0, "the uncertainty of the match is not finite (NaN or inf): not usable")
        res.details["failure"] = "uncertainty"
        res.details["T_candidate"] = T_match
        return res
    excess = _sigma_excess(unc, params)
    if excess is not None:
        res.verdict = "ambiguous"
        res.reasons.insert(0, excess)
        res.details["T_candidate"] = T_match
        return res
    res.T_match = T_match
    return res


def evaluate(
    current: PreparedCloud,
    template: PreparedCloud,
    T_match: np.ndarray,
    params: FineParams,
    *,
    method: str,
    iterations: int = 0,
    converged: bool = True,
    edges: tuple[EdgeSet, EdgeSet] | None = None,
) -> RegistrationResult:
    """Score *T_match*, compute its uncertainty and decide the verdict (shared by every matcher).

    ``edges`` (current, template edge sets): check the contour match and add the edge rows to the
    Hessian. ``details["min_stiffness_ratio"]`` is set whenever the uncertainty could be computed
    (also for a result that did not converge); ``details["failure"]`` says why a result failed
    (``overlap``, ``edges``: the pose is refuted; ``convergence``; ``uncertainty``)."""
    _, inlier_d, trunc = params.distances(template)
    sc = score_alignment(
        current.points,
        template,
        T_match,
        inlier_distance_m=inlier_d,
        truncation_m=trunc,
        num_threads=params.num_threads,
    )
    res = RegistrationResult(
        verdict="ok",
        method=method,
        fitness=sc.fitness,
        inlier_rmse=sc.inlier_rmse,
        score=sc.score,
        iterations=iterations,
        converged=converged,
    )
    reasons = _overlap_reasons(sc, inlier_d, params)
    if reasons:  # too little overlap: no uncertainty
        return _refuse(res, reasons, T_match, "overlap")
    edge_term = _EdgeTerm() if edges is None else _contour_check(res, reasons, edges, T_match, params.edges)
    unc = _match_uncertainty(current, template, T_match, sc, params, edges, edge_term)
    res.details["min_stiffness_ratio"] = float(np.min(unc.eigen_ratios))
    if not converged:
        ran = (
            f"{params.edges.max_iterations} Gauss-Newton steps with edges"
            if edges is not None
            else f"{params.max_iterations} iterations and {params.recheck_iterations} more"
        )
        reasons.append(f"{method} did not converge: still moving after {ran}")
    if reasons:
        return _refuse(res, reasons, T_match, "edges" if edge_term.refutes else "convergence")
    return _uncertainty_verdict(res, unc, T_match, params)


def _recheck(
    current: PreparedCloud, template: PreparedCloud, T: np.ndarray, settings: IcpSettings, params: FineParams
) -> tuple[np.ndarray, bool]:
    """Re-run the backend briefly from *T*; converged if it hardly moves (see FineParams).
    ``recheck_iterations <= 0`` disables the check (used for the coarse stage of global matching)."""
    if params.recheck_iterations <= 0:
        return T, True
    out = run_backend(params.backend, current, template, T, replace(settings, max_iterations=params.recheck_iterations))
    T2 = out.T_match
    if not (np.all(np.isfinite(T2)) and tf.is_rotation(T2[:3, :3], tol=1e-6)):
        return T, False
    c = current.centroid[None, :]
    moved = float(np.linalg.norm(tf.transform_points(T2, c) - tf.transform_points(T, c)))
    turned = tf.angle_between(T[:3, :3], T2[:3, :3])
    ok = moved <= 10.0 * params.translation_eps_m and turned <= 10.0 * params.rotation_eps_rad
    return (T if ok else tf.T_from_Rt(tf.orthonormalize(T2[:3, :3]), T2[:3, 3])), ok


def refine(
    current: PreparedCloud, template: PreparedCloud, T_init: np.ndarray, params: FineParams
) -> RegistrationResult:
    """Run the backend from *T_init* on prepared clouds and evaluate (no input validation)."""
    max_corr, _, _ = params.distances(template)
    settings = IcpSettings(
        max_correspondence_m=max_corr,
        max_iterations=params.max_iterations,
        rotation_eps_rad=params.rotation_eps_rad,
        translation_eps_m=params.translation_eps_m,
        num_threads=params.num_threads,
        kiss_voxel_m=params.kiss_voxel_m or max_corr,
        kiss_points_per_voxel=params.kiss_points_per_voxel,
    )
    out = run_backend(params.backend, current, template, T_init, settings)
    T = out.T_match
    method = f"fine:{params.backend}"
    if not (np.all(np.isfinite(T)) and tf.is_rotation(T[:3, :3], tol=1e-6)):
        return failed(method, f"{params.backend} returned a non-rigid or non-finite transform")
    T = tf.T_from_Rt(tf.orthonormalize(T[:3, :3]), T[:3, 3])
    iterations, converged = out.iterations, out.converged
    note = None
    if _wants_edges(template, params):
        # weak geometry: the surfaces do not fix the in-plane pose (GICP may still be creeping
        # along it, so no recheck); the edge stage takes over from here
        res, note = _refine_with_edges(current, template, T, params, method=method, iterations=iterations)
        if res is not None:
            return res
    if not converged:
        T, converged = _recheck(current, template, T, settings, params)
    if params.polish_voxel_m is not None:
        current = current.at_voxel(params.polish_voxel_m)
        template = template.at_voxel(params.polish_voxel_m)
        polish = replace(
            settings,
            max_correspondence_m=params.polish_correspondence_m or max(current.voxel_size_m, 1e-3),
            max_iterations=params.polish_max_iterations,
            translation_eps_m=params.polish_translation_eps_m or settings.translation_eps_m,
            rotation_eps_rad=params.polish_rotation_eps_rad or settings.rotation_eps_rad,
        )
        out = run_backend(params.polish_backend or params.backend, current, template, T, polish)
        if not (np.all(np.isfinite(out.T_match)) and tf.is_rotation(out.T_match[:3, :3], tol=1e-6)):
            return failed(method, f"{params.backend} returned a non-rigid or non-finite transform (polish)")
        T = tf.T_from_Rt(tf.orthonormalize(out.T_match[:3, :3]), out.T_match[:3, 3])
        iterations, converged = iterations + max(out.iterations, 0), out.converged
        if not converged:
            T, converged = _recheck(current, template, T, polish, params)
        params = replace(params, max_correspondence_m=None, inlier_distance_m=None, truncation_m=None)
    res = evaluate(current, template, T, params, method=method, iterations=iterations, converged=converged)
    if note:
        res.reasons.append(note)
    return res


def template_stiffness(template: PreparedCloud, params: FineParams) -> float:
    """Smallest stiffness ratio of the template's own surfaces AWAY FROM THEIR BORDERS (its
    downsampled points against themselves, without those within 1.5 resolutions of an edge point;
    cached). Below ``weak_ratio`` the surfaces alone leave a direction to the normals at the
    contour, whose tilt is set by the sampling, not by the part (measured: planar_plate seen from
    above 7e-5, the symmetric plate 7e-5, planar_plate seen 30 deg oblique 3e-3, feature_part 7e-3
    to 9e-3, a CAD-model template of the plate 0.06). With the contour points kept the plate reads
    5e-4: too close to the limit to tell it reliably. A template that reads >= 10 ``weak_ratio`` with
    its borders is taken as it is (the border detection is skipped)."""
    key = ("interior_stiffness", params.weak_ratio, params.edges)
    if key not in template._cache:
        P, N = template.points, template.normals()
        whole = float(np.min(pose_uncertainty(P, P, N, weak_ratio=params.weak_ratio).eigen_ratios))
        if whole >= 10.0 * params.weak_ratio:  # stiff even with its borders (feature_part: 0.03)
            template._cache[key] = whole
            return whole
        edges = detect_edges(P, N, params.edges, viewpoint=template.viewpoint)
        keep = np.ones(len(P), dtype=bool)
        if len(edges):
            d, _ = edges.tree().query(P, k=1)
            keep = d > 1.5 * template.resolution()
        ratio = 0.0
        if np.count_nonzero(keep) >= 7:
            unc = pose_uncertainty(P[keep], P[keep], N[keep], weak_ratio=params.weak_ratio)
            ratio = float(np.min(unc.eigen_ratios))
        template._cache[key] = ratio
    return template._cache[key]


def _wants_edges(template: PreparedCloud, params: FineParams) -> bool:
    mode = params.edges.mode
    if mode == "off":
        return False
    return mode == "on" or template_stiffness(template, params) < params.weak_ratio


def _refine_with_edges(
    current: PreparedCloud,
    template: PreparedCloud,
    T: np.ndarray,
    params: FineParams,
    *,
    method: str,
    iterations: int,
) -> tuple[RegistrationResult | None, str | None]:
    """The edge stage (see edges.py): refine *T* with the contours and evaluate with them (on the
    polish clouds when a polish is asked for). (None, why) without enough edge points."""
    ep = params.edges
    cur_e, tmpl_e = edge_set(current, ep), edge_set(template, ep)
    if min(len(cur_e), len(tmpl_e)) < ep.min_edges:
        return None, (
            f"weak geometry, but the edge term was not used: {len(cur_e)} current / {len(tmpl_e)} template "
            f"edge points (need {ep.min_edges})"
        )
    # edge rows at full resolution throughout; surface rows first on the fine-voxel clouds with the
    # fine stage's correspondence distance (wide basin), then on the evaluation clouds (the polish
    # clouds when a polish is asked for) with the inlier distances
    max_corr, _, _ = params.distances(template)
    edge_gate = ep.inlier_factor * max(cur_e.spacing, tmpl_e.spacing)
    phases = [(current, template, max_corr, max_corr)]
    if params.polish_voxel_m is not None:  # evaluated where a polish would have been
        current = current.at_voxel(params.polish_voxel_m)
        template = template.at_voxel(params.polish_voxel_m)
        params = replace(params, max_correspondence_m=None, inlier_distance_m=None, truncation_m=None)
    _, inlier_d, _ = params.distances(template)
    phases.append((current, template, inlier_d, edge_gate))
    T2, it, converged = edge_icp(
        phases,
        cur_e,
        tmpl_e,
        T,
        iterations=ep.max_iterations,
        translation_eps_m=params.translation_eps_m,
        rotation_eps_rad=params.rotation_eps_rad,
        min_cos=ep.min_cos,
        num_threads=params.num_threads,
    )
    if not (np.all(np.isfinite(T2)) and tf.is_rotation(T2[:3, :3], tol=1e-6)):
        return failed(method, "edge refinement returned a non-rigid or non-finite transform"), None
    T2 = tf.T_from_Rt(tf.orthonormalize(T2[:3, :3]), T2[:3, 3])
    res = evaluate(
        current,
        template,
        T2,
        params,
        method=method + "+edges",
        iterations=max(iterations, 0) + it,
        converged=converged,
        edges=(cur_e, tmpl_e),
    )
    return res, None


def register_fine(
    current: Any,
    template: Any,
    T_init: Any = None,
    params: FineParams | None = None,
) -> RegistrationResult:
    """Fine registration of the CURRENT cloud onto the TEMPLATE cloud from ``T_init`` (default identity).

    *current* and *template* are (N, 3) arrays in metres, Open3D clouds, or :class:`PreparedCloud`
    (a template prepared once is reused as is). Returns a :class:`RegistrationResult` whose
    ``T_match`` satisfies ``p_template = T_match @ p_current``; never raises on bad input (the result
    is ``failed`` with the reason).
    """
    params = params or FineParams()
    method = f"fine:{params.backend}"
    t0 = time.perf_counter()
    if params.backend not in BACKENDS:
        return failed(method, f"unknown backend {params.backend!r}; choose one of {', '.join(BACKENDS)}")
    try:
        T0 = as_initial_transform(T_init)
        tmpl = prepare_cloud(template, params.preprocess, name="template")
        cur = prepare_cloud(current, params.preprocess, name="current")
    except InvalidInputError as exc:
        return failed(method, str(exc))
    t1 = time.perf_counter()
    try:
        result = refine(cur, tmpl, T0, params)
    except Exception as exc:  # a backend error must not escape the stage
        return failed(method, f"{params.backend} raised {type(exc).__name__}: {exc}")
    result.timings_s = {"preprocess": t1 - t0, "register": time.perf_counter() - t1}
    return result
