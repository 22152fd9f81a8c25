"""Human-readable report of a hand-eye / robot-world CalibrationResult, in mm and degrees.

The result itself stays in SI units; this module is the only place that converts for people
(estimates with 1-sigma, pose-chain spread, noise and the limits it was held to, per-sample residual
table named by the samples' own ids, verdict, reasons, advice). ``format_report(result)`` returns
plain text for the CLI and logs.
"""

from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from plugins.calibration.result import CalibrationResult

__all__ = ["format_report", "residual_table", "sample_labels"]

_MM, _DEG = 1e3, float(np.rad2deg(1.0))


def _pose_lines(name: str, T: np.ndarray, std: np.ndarray | None) -> list[str]:
    t = np.asarray(T)[:3, 3] * _MM
    rot = Rotation.from_matrix(np.asarray(T)[:3, :3])
    q = rot.as_quat()
    q = -q if q[3] < 0 else q
    lines = [
        f"{name}:",
        f"  translation [mm]     {t[0]:+11.3f} {t[1]:+11.3f} {t[2]:+11.3f}",
        f"  rotation vector [deg]{rot.as_rotvec(degrees=True)[0]:+11.4f} "
        f"{rot.as_rotvec(degrees=True)[1]:+11.4f} {rot.as_rotvec(degrees=True)[2]:+11.4f}",
        f"  quaternion xyzw      {q[0]:+.6f} {q[1]:+.6f} {q[2]:+.6f} {q[3]:+.6f}",
    ]
    if std is not None:
        lines.append(
            f"  1 sigma: translation {std[0] * _MM:.3f} {std[1] * _MM:.3f} {std[2] * _MM:.3f} mm, "
            f"rotation {std[3] * _DEG:.4f} {std[4] * _DEG:.4f} {std[5] * _DEG:.4f} deg (parent-frame axes)"
        )
    return lines


def sample_labels(result: CalibrationResult) -> list[str]:
    """The id of each residual row: ``estimate["sample_labels"]`` (the ids of the input, e.g. of its
    file), else the row's ``sample_index`` (position in the caller's input)."""
    R = np.asarray(result.residuals)
    labels = result.estimate.get("sample_labels")
    if labels is not None and len(labels) == len(R):
        return [str(x) for x in labels]
    k = result.residual_names.index("sample_index")
    return [str(int(i)) for i in R[:, k]]


def residual_table(result: CalibrationResult, max_rows: int = 200) -> list[str]:
    """One line per sample: chain, robot and camera residuals (mm, deg), Mahalanobis^2, weight, flag."""
    if result.residuals is None:
        return []
    R = np.asarray(result.residuals)
    col = {n: i for i, n in enumerate(result.residual_names)}
    if "chain_tx" not in col:  # from images: per view, in pixels
        return _pixel_table(result, R, max_rows)

    def norm(prefix: str, part: str) -> np.ndarray:
        names = [f"{prefix}_{part}{a}" for a in "xyz"]
        return np.linalg.norm(R[:, [col[n] for n in names]], axis=1)

    out = np.zeros(len(R), dtype=bool) if result.outliers is None else np.asarray(result.outliers)
    labels = sample_labels(result)
    w = max(6, *(len(x) for x in labels))
    lines = [
        f"  {'sample':>{w}}  chain_mm chain_deg  robot_mm robot_deg  camera_mm camera_deg   maha2  weight",
    ]
    rows = list(range(len(R)))[:max_rows]
    for k in rows:
        lines.append(
            f"  {labels[k]:>{w}} {norm('chain', 't')[k] * _MM:9.3f} "
            f"{norm('chain', 'r')[k] * _DEG:9.4f} {norm('robot', 't')[k] * _MM:9.3f} "
            f"{norm('robot', 'r')[k] * _DEG:9.4f} {norm('camera', 't')[k] * _MM:10.3f} "
            f"{norm('camera', 'r')[k] * _DEG:10.4f} {R[k, col['mahalanobis2']]:7.2f} "
            f"{R[k, col['weight']]:7.3f}{'  OUTLIER' if out[k] else ''}"
        )
    if len(R) > max_rows:
        lines.append(f"  ... {len(R) - max_rows} more")
    return lines


def _pixel_table(result: CalibrationResult, R: np.ndarray, max_rows: int) -> list[str]:
    """One line per view of an image-based calibration: its residual columns (pixels), outlier flag."""
    out = np.zeros(len(R), dtype=bool) if result.outliers is None else np.asarray(result.outliers)
    labels = [str(x) for x in result.estimate.get("sample_labels", [])]
    labels = labels if len(labels) == len(R) else [str(k) for k in range(len(R))]
    w = max(6, *(len(x) for x in labels))
    lines = ["  " + f"{'view':>{w}}" + "".join(f" {n:>15}" for n in result.residual_names)]
    for k in range(min(len(R), max_rows)):
        cells = "".join(f" {v:15.3f}" for v in R[k])
        lines.append(f"  {labels[k]:>{w}}{cells}{'  LEFT OUT' if out[k] else ''}")
    if len(R) > max_rows:
        lines.append(f"  ... {len(R) - max_rows} more")
    return lines


def format_report(result: CalibrationResult, *, per_sample: bool = True) -> str:
    """Plain-text report (mm, degrees) of a hand-eye or robot-world calibration result."""
    m = result.metrics
    setup = result.estimate.get("setup", "set-up not determined")
    found = " found from the data" if m.get("setup_found_from_data") else ""
    lines = [
        f"{result.kind.replace('_', '-')} calibration ({setup}{found}): verdict {result.verdict.upper()}",
        f"method: {result.method}",
    ]
    if result.covariance is not None and result.param_names:
        std = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
        names = [result.param_names[0].split(".")[0], result.param_names[6].split(".")[0]]
        for k, name in enumerate(names):
            lines += _pose_lines(name, result.estimate[name], std[6 * k : 6 * k + 6])
    if "n_samples" in m:
        lines.append(
            f"samples: {int(m['n_samples'])} used of {int(m.get('n_samples_given', m['n_samples']))} given, "
            f"{int(m['n_outliers'])} outlier(s)"
        )
        lines.append(
            f"pose-chain spread (each sample's own {result.param_names[6].split('.')[0]}): RMS "
            f"{m['chain_spread_trans_rms_m'] * _MM:.3f} mm / {m['chain_spread_rot_rms_rad'] * _DEG:.4f} deg, "
            "max "
            f"{m['chain_spread_trans_max_m'] * _MM:.3f} mm / {m['chain_spread_rot_max_rad'] * _DEG:.4f} deg"
        )
        lines.append(
            f"residual RMS: camera {m['camera_residual_trans_rms_m'] * _MM:.3f} mm / "
            f"{m['camera_residual_rot_rms_rad'] * _DEG:.4f} deg, robot "
            f"{m['robot_residual_trans_rms_m'] * _MM:.3f} mm / "
            f"{m['robot_residual_rot_rms_rad'] * _DEG:.4f} deg; variance factor {m['variance_factor']:.3f} "
            f"(dof {int(m['dof'])})"
        )
        lines.append(
            f"noise ({'estimated' if m.get('noise_estimated') else 'declared'}): robot "
            f"{m['noise_robot_trans_m'] * _MM:.3f} mm / {m['noise_robot_rot_rad'] * _DEG:.4f} deg, camera "
            f"{m['noise_camera_trans_m'] * _MM:.3f} mm / {m['noise_camera_rot_rad'] * _DEG:.4f} deg"
            + (
                f" (the median of per-sample covariances: those given times {m['noise_camera_covariance_factor']:.3g})"
                if m.get("camera_covariances_given")
                else ""
            )
        )
        if m.get("noise_estimated") and "noise_limit_camera_rot_rad" in m:
            limits = [
                f"{who} {m[f'noise_limit_{who}_rot_rad'] * _DEG:.3g} deg / "
                f"{m[f'noise_limit_{who}_trans_m'] * _MM:.3g} mm"
                for who in ("robot", "camera")
            ]
            lines.append(f"noise limits (an estimated noise above one fails): {', '.join(limits)}")
        if m.get("noise_heavy_tail"):
            lines.append(
                f"heavy-tailed noise: the samples' costs fit a t tail ({m['noise_tail_dof']:.3g} dof); "
                f"outlier bound {m['outlier_bound']:.1f} (studentized cost) instead of the Gaussian one"
            )
    if result.covariance is not None and result.param_names:
        x = result.param_names[0].split(".")[0]
        thr = result.confidence_threshold(6)
        if "covariance_dof" in m:
            nu = m["covariance_dof"]
            how = "Kenward-Roger" if "covariance_f_scale" in m else "variance factor"
            lines.append(
                f"95 % confidence region of {x}: Mahalanobis^2 <= {thr:.2f} (F(6, {nu:.0f}), {how}: the "
                f"covariance rests on an estimated noise; chi2(6) would give {stats.chi2.ppf(0.95, 6):.2f})"
            )
        else:
            lines.append(f"95 % confidence region of {x}: Mahalanobis^2 <= {thr:.2f} (chi2(6), declared noise)")
    if "excitation_min_rad" in m:
        lines.append(
            f"motion: largest relative rotation {m['max_relative_rotation_rad'] * _DEG:.1f} deg, "
            f"weakest direction turned by {m['excitation_min_rad'] * _DEG:.1f} deg RMS"
        )
    if per_sample and result.residuals is not None:
        lines.append("per-sample residuals:")
        lines += residual_table(result)
    return "\n".join(lines + result.reason_lines())
