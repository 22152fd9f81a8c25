"""Human-facing output of a kinematic calibration: convergence plot (PNG) and before/after table."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from plugins.calibration.kinematics.calibrate import KinematicCalibration


def plot_convergence(cal: KinematicCalibration, path: str | Path) -> Path:
    """Whitened residual RMS per iteration (1 = the stated noise) and before/after errors, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    n_res = cal.result.residuals.size
    rms = [np.sqrt(2 * h["cost"] / n_res) for h in cal.lm.history]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    ax = axes[0]
    ax.semilogy([h["iteration"] for h in cal.lm.history], rms, "o-")
    ax.axhline(1.0, color="grey", linestyle="--", label="noise floor")
    ax.legend()
    ax.set_xlabel("iteration")
    ax.set_ylabel("residual RMS / stated noise sigma")
    ax.set_title(f"convergence ({cal.result.method})", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax = axes[1]
    labels, before, after = [], [], []
    for row in cal.table:
        labels.append(f"{row['set']} (n={row['n']})")
        before.append(row["before"]["rms_mm"])
        after.append(row["after"]["rms_mm"])
    x = np.arange(len(labels))
    ax.bar(x - 0.2, before, 0.4, label="before")
    ax.bar(x + 0.2, after, 0.4, label="after")
    ax.set_yscale("log")
    ax.set_xticks(x, labels)
    ax.set_ylabel("3-D position error RMS (mm)")
    ax.legend()
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def format_table(cal: KinematicCalibration) -> str:
    """Plain-text before/after table (mm; degrees for orientation when measured)."""
    cols = ["rms_mm", "max_mm", "rms_x_mm", "rms_y_mm", "rms_z_mm"]
    if cal.table and "rms_rot_deg" in cal.table[0]["before"]:
        cols.append("rms_rot_deg")
    lines = [f"{'set':<12}{'n':>5}  {'':<7}" + "".join(f"{c:>12}" for c in cols)]
    for row in cal.table:
        for when in ("before", "after"):
            vals = "".join(f"{row[when][c]:>12.4f}" for c in cols)
            lines.append(f"{row['set']:<12}{row['n']:>5}  {when:<7}{vals}")
        if "expected_rms_mm" in row:
            lines.append(
                f"{row['set']} rms_mm expected for a correct model: {row['expected_rms_mm']:.4f} "
                f"(after / expected = {row['after']['rms_mm'] / row['expected_rms_mm']:.3f}; the noise floor "
                "raised by the calibrated parameters' own uncertainty, about sqrt(1 + p/n))"
            )
    return "\n".join(lines)
