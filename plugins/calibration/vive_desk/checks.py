"""Pre-solve checks of Vive desk contact data: units, duplicates, point geometry, pose consistency.

Hard errors (the data cannot be what the caller meant) raise ``ValueError``; quality findings are
returned as :class:`~plugins.calibration.pose_lsq.Issue` objects that the solver turns into the verdict.
The pose-consistency bands are seed 001's (max pairwise tracker orientation difference at one
fixture orientation: < 0.5 deg excellent, < 1 deg good, < 2 deg recalibrate, >= 2 deg unusable).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.distance import pdist, squareform
from scipy.spatial.transform import Rotation

from plugins.calibration.pose_lsq import Issue, looks_like_millimetres
from plugins.calibration.vive_desk.data import ViveDeskData

F64 = NDArray[np.float64]

SAME_POINT_M = 1e-3  # contact points closer than this are the same point (repeated measurement)
SAME_ORIENTATION_RAD = np.radians(0.01)  # nominal fixture orientations closer than this are one group


@dataclass(frozen=True)
class ViveThresholds:
    """Acceptance thresholds; defaults are seed 001's numbers where the seed gives one."""

    consistency_excellent_deg: float = 0.5
    consistency_good_deg: float = 1.0
    consistency_fail_deg: float = 2.0
    accept_mean_position_m: float = 1.0e-3  # seed: mean position error < 1 mm
    accept_mean_rotation_deg: float = 0.5  # seed: mean rotation error < 0.5 deg
    min_point_spacing_m: float = 0.10  # seed: points closer than 10 cm are not recommended
    collinear_width_m: float = 0.01  # RMS distance of the points from their best-fit line
    max_predicted_position_rms_m: float = 1.0e-3  # predicted RMS error of a calibrated translation (seed: < 1 mm)
    max_predicted_rotation_rms_deg: float = 0.5  # predicted RMS error of a calibrated rotation (seed: < 0.5 deg)
    outlier_p_value: float = 1e-3
    chi2_p_value: float = 1e-3


def check_units(data: ViveDeskData) -> None:
    """Raise ValueError when positions look like millimetres or desk and tracker disagree in scale."""
    q = data.tcp_positions_desktop
    t = data.T_base_tracker[:, :3, 3]
    if looks_like_millimetres(data.desk_points, 5.0):
        raise ValueError(
            f"desk points reach {np.max(np.abs(data.desk_points)):.1f}: that looks like millimetres; "
            "give metres (or 'units': 'mm' in the data file)"
        )
    if looks_like_millimetres(data.tcp_offsets_desktop, 2.0):
        raise ValueError(
            f"contact offset reaches {np.max(np.abs(data.tcp_offsets_desktop)):.1f}: that looks like "
            "millimetres; give metres"
        )
    if looks_like_millimetres(t, 20.0):
        raise ValueError(
            f"tracker positions reach {np.max(np.abs(t)):.1f}: a Vive base station covers a few metres, "
            "so these look like millimetres; give metres"
        )
    spread_q = float(np.sqrt(np.mean(np.sum((q - q.mean(0)) ** 2, axis=1))))
    spread_t = float(np.sqrt(np.mean(np.sum((t - t.mean(0)) ** 2, axis=1))))
    if spread_q > 0.01 and spread_t > 0:
        ratio = spread_t / spread_q
        if ratio > 5.0 or ratio < 0.2:
            raise ValueError(
                f"mixed units: the tracker positions spread {spread_t:.4g} but the desk points "
                f"{spread_q:.4g} (ratio {ratio:.3g}; a rigid desk gives about 1, the lever arm of a "
                "turned tool changes it by tens of percent at most); the two are in different units "
                "(mm / cm / m?)"
            )


def distinct_points(points: F64, tol: float = SAME_POINT_M) -> tuple[F64, NDArray[np.int_]]:
    """(distinct points, index of the distinct point of each input point), greedy clustering."""
    reps: list[F64] = []
    idx = np.empty(len(points), dtype=int)
    for i, p in enumerate(points):
        for k, r in enumerate(reps):
            if np.linalg.norm(p - r) < tol:
                idx[i] = k
                break
        else:
            reps.append(p)
            idx[i] = len(reps) - 1
    return np.array(reps).reshape(-1, 3), idx


def orientation_groups(data: ViveDeskData) -> list[NDArray[np.int_]]:
    """Indices of samples sharing one nominal fixture orientation (free-orientation samples excluded)."""
    groups: list[list[int]] = []
    reps: list[F64] = []
    for i in np.flatnonzero(data.orientation_known):
        R = data.R_desktop_tcp[i]
        for g, Rr in zip(groups, reps, strict=True):
            if Rotation.from_matrix(Rr.T @ R).magnitude() < SAME_ORIENTATION_RAD:
                g.append(int(i))
                break
        else:
            groups.append([int(i)])
            reps.append(R)
    return [np.array(g) for g in groups]


def check_samples(data: ViveDeskData, thresholds: ViveThresholds) -> tuple[list[Issue], dict[str, float]]:
    """Count, duplicates and geometry of the contact points. Raises ValueError on unusable input."""
    issues: list[Issue] = []
    T = data.T_base_tracker
    q = data.tcp_positions_desktop
    for i in range(data.n):
        for j in range(i):
            if np.allclose(q[i], q[j], atol=1e-9) and np.allclose(T[i], T[j], atol=1e-9):
                raise ValueError(
                    f"samples {data.labels[j]} and {data.labels[i]} are identical (same desk point and "
                    "same tracker pose to 1e-9): a copied row; remove it"
                )
    pts, idx = distinct_points(q)
    if len(pts) < 3:
        raise ValueError(
            f"need at least 3 distinct contact points (seed 001), got {len(pts)} distinct of {data.n} samples"
        )
    repeats = data.n - len(pts)
    if repeats:
        issues.append(Issue("info", f"{repeats} repeated contact(s) of the same desk point: averaged by the fit"))
    centred = pts - pts.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    width = float(s[1] / np.sqrt(len(pts)))
    d = squareform(pdist(pts))
    np.fill_diagonal(d, np.inf)
    min_spacing = float(d.min())
    if min_spacing < thresholds.min_point_spacing_m:
        a, b = np.unravel_index(np.argmin(d), d.shape)
        la, lb = data.labels[int(np.flatnonzero(idx == a)[0])], data.labels[int(np.flatnonzero(idx == b)[0])]
        issues.append(
            Issue(
                "warning",
                f"contact points {la} and {lb} are {min_spacing * 1e3:.0f} mm apart "
                f"(< {thresholds.min_point_spacing_m * 1e3:.0f} mm): measurement noise is a large part "
                "of their separation",
                "spread the contact points at least 10 cm apart, covering the working area (seed 001)",
            )
        )
    metrics = {
        "n_samples": float(data.n),
        "n_distinct_points": float(len(pts)),
        "point_line_width_mm": width * 1e3,
        "min_point_spacing_mm": min_spacing * 1e3,
    }
    return issues, metrics


def collinearity_issue(width_m: float, structurally_deficient: bool, thresholds: ViveThresholds) -> Issue | None:
    """Issue for (nearly) collinear contact points; degenerate when the design is also rank deficient."""
    if width_m >= thresholds.collinear_width_m:
        return None
    return Issue(
        "degenerate" if structurally_deficient else "warning",
        f"contact points are (nearly) collinear (RMS distance from their best-fit line "
        f"{width_m * 1e3:.1f} mm): the desk's rotation about that line is not determined",
        "add a contact point well off the line (e.g. a triangle or square layout, >= 10 cm sides)",
    )


def pose_consistency(data: ViveDeskData, thresholds: ViveThresholds) -> tuple[list[Issue], dict[str, float]]:
    """Seed 001's check: max pairwise tracker orientation difference within each fixture orientation."""
    issues: list[Issue] = []
    worst = 0.0
    groups = orientation_groups(data)
    for g_no, g in enumerate(groups):
        if g.size < 2:
            continue
        rots = Rotation.from_matrix(data.T_base_tracker[g, :3, :3])
        max_deg = 0.0
        for a in range(g.size):
            max_deg = max(max_deg, float(np.degrees(np.max((rots[a].inv() * rots).magnitude()))))
        worst = max(worst, max_deg)
        tag = f"fixture orientation {g_no + 1}" if len(groups) > 1 else "the fixture orientation"
        t = thresholds
        if max_deg < t.consistency_excellent_deg:
            issues.append(Issue("info", f"pose consistency at {tag}: {max_deg:.2f} deg, excellent (< 1 mm expected)"))
        elif max_deg < t.consistency_good_deg:
            issues.append(Issue("info", f"pose consistency at {tag}: {max_deg:.2f} deg, good (1-2 mm expected)"))
        elif max_deg < t.consistency_fail_deg:
            issues.append(
                Issue(
                    "warning",
                    f"pose consistency at {tag}: {max_deg:.2f} deg, large (2-5 mm expected)",
                    "recalibrate with the tool seated firmly in the fixture (seed 001: keep the "
                    "orientation within 0.5 deg)",
                )
            )
        else:
            issues.append(
                Issue(
                    "failed",
                    f"pose consistency at {tag}: {max_deg:.2f} deg >= {t.consistency_fail_deg} deg, "
                    "the calibration is not reliable",
                    "use the calibration fixture; a hand-held tool scatters 3-10 deg (seed 001)",
                )
            )
    return issues, {"pose_consistency_max_deg": worst, "n_orientation_groups": float(len(groups))}
