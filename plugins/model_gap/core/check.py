"""Scoring a stored model on new measurements: its errors against the noise floor, nothing refitted.

The model-gap workflow builds a model; this is the other half of using it: does that model, as
stored, predict measurements it has never seen? The problem side (e.g.
:mod:`plugins.model_gap.check`) predicts the new data with the stored model -- refitting
nothing, or only what the user names (a new tool's point) -- and hands over the residuals as a
:class:`~.interfaces.Linearisation` whose Jacobian holds only the refitted parameters. Here:

* **errors**: mean and RMS of the 3-D error, its largest value, per axis, in the report unit;
* **against the noise floor**: ``sqrt(m) sigma`` (what the noise alone gives) and the *expected* RMS
  of a correct model, ``floor * sqrt(1 + p / n)`` with ``p`` / ``n`` the parameters and residuals of
  the stored model's own fit (its parameters are uncertain too; for new poses like the fit's,
  docs/kinematic_calibration.md); the noise check (:func:`.verdict.check_noise`) with the residuals
  scaled by that factor and ``dof`` = residuals - refitted parameters;
* **the verdict**: ``gap`` when the residuals change systematically -- the noise-independent F-tests
  of :mod:`.structure` (a constant offset included: nothing absorbs it when nothing is refitted) --,
  else ``ok``. As for the workflow, a different stated noise does not change it; the noise check
  says when the stated noise and the residuals disagree and which to believe;
* where the residuals concentrate (:mod:`.localise`), for the report and the figure.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from engine.plain_data import plain
from plugins.model_gap.core.interfaces import F64, Feature, Linearisation
from plugins.model_gap.core.localise import FeatureGap, localise
from plugins.model_gap.core.structure import StructureTest, residual_structure
from plugins.model_gap.core.verdict import NoiseCheck, check_noise

CHECK_FORMAT = "vgr.gap_check/1"
CHECK_VERDICTS = ("ok", "gap")


@dataclass
class ModelCheck:
    """A stored model scored on new measurements (SI units; see the module docstring)."""

    verdict: str  # ok | gap
    reason: str
    residual: F64  # (N, m) measured - predicted
    whitened: F64
    mean_error: float  # mean 3-D error norm
    rms: float
    max: float
    rms_axis: list[float]
    mean_axis: list[float]
    noise_floor: float  # sqrt(m) sigma
    expected_factor: float  # sqrt(1 + p / n) of the stored model's fit
    noise: NoiseCheck
    structure: StructureTest
    localisation: list[FeatureGap]
    refitted: dict[str, dict[str, float]] = field(default_factory=dict)  # name -> stored, value, std (SI)
    model: dict[str, Any] = field(default_factory=dict)  # what was checked (kind, source, effects ...)
    report_unit: str = ""
    report_scale: float = 1.0
    files: dict[str, str] = field(default_factory=dict)

    @property
    def expected_rms(self) -> float:
        return self.noise_floor * self.expected_factor


def check_residuals(
    lin: Linearisation,
    features: list[Feature],
    *,
    expected_factor: float = 1.0,
    alpha: float = 1e-3,
    noise_source: str = "given",
    refitted: dict[str, dict[str, float]] | None = None,
    model: dict[str, Any] | None = None,
    unit: str = "",
    scale: float = 1.0,
) -> ModelCheck:
    """Score the residuals of ``lin`` (the stored model on new data; see the module docstring)."""
    phys = lin.physical_residual()
    m = phys.shape[1]
    norms = np.linalg.norm(phys, axis=1)
    M = lin.residual.size
    p = int(np.linalg.matrix_rank(lin.jacobian.reshape(M, -1))) if lin.jacobian.shape[2] else 0
    chi2 = float(np.sum(lin.residual**2)) / expected_factor**2
    stated = float(np.sqrt(np.mean(lin.sigma**2)))
    structure = residual_structure(lin, features, alpha)
    noise = check_noise(chi2, M - p, stated, structure, alpha, noise_source)
    rms = float(np.sqrt(np.mean(norms**2)))
    floor = stated * np.sqrt(m)
    fig = (
        f"RMS {rms * scale:.4g} {unit} against {floor * expected_factor * scale:.4g} {unit} expected "
        f"(noise floor {floor * scale:.4g} {unit} x {expected_factor:.3f} for the model's own uncertainty), "
        f"mean {float(norms.mean()) * scale:.4g}, max {float(norms.max()) * scale:.4g} {unit}"
    )
    if structure.found:
        verdict = "gap"
        reason = (
            f"the model does not predict these measurements: the residuals change systematically, "
            f"{structure.describe()}; {fig}; {noise.note}"
        )
    else:
        verdict = "ok"
        reason = f"the model predicts these measurements (no systematic residual left): {fig}; {noise.note}"
    return ModelCheck(
        verdict,
        reason,
        phys,
        lin.residual.copy(),
        float(norms.mean()),
        rms,
        float(norms.max()),
        np.sqrt(np.mean(phys**2, axis=0)).tolist(),
        phys.mean(axis=0).tolist(),
        float(floor),
        float(expected_factor),
        noise,
        structure,
        localise(lin, features),
        dict(refitted or {}),
        dict(model or {}),
        unit,
        scale,
    )


def check_report_dict(c: ModelCheck) -> dict[str, Any]:
    """``check_report.json`` (format ``vgr.gap_check/1``), lengths in the report unit."""
    s, u = c.report_scale, c.report_unit
    n = c.noise
    return {
        "format": CHECK_FORMAT,
        "verdict": c.verdict,
        "reason": c.reason,
        "model": c.model,
        "n_samples": int(c.residual.shape[0]),
        f"mean_error_{u}": c.mean_error * s,
        f"rms_{u}": c.rms * s,
        f"max_{u}": c.max * s,
        f"rms_axis_{u}": [v * s for v in c.rms_axis],
        f"mean_axis_{u}": [v * s for v in c.mean_axis],
        f"noise_floor_{u}": c.noise_floor * s,
        f"expected_rms_{u}": c.expected_rms * s,
        "expected_factor": c.expected_factor,
        "rms_over_expected": c.rms / c.expected_rms if c.expected_rms > 0 else None,
        "noise_check": {
            "source": n.source,
            f"stated_sigma_{u}": n.stated_sigma * s,
            f"residual_sigma_{u}": n.residual_sigma * s,
            "ratio": n.ratio,
            "chi2": n.chi2,
            "dof": n.dof,
            "p_above": n.p_above,
            "p_below": n.p_below,
            "agrees": n.agrees,
            "believe": n.believe,
            "note": n.note,
        },
        "residual_structure": {
            "found": c.structure.found,
            "alpha_familywise": c.structure.alpha,
            "n_tests": c.structure.n_tests,
            "tests": [
                {"design": f.design, "label": f.label, "f_stat": f.f_stat, "p_corrected": f.p_corrected}
                for f in c.structure.findings[:8]
            ],
        },
        "refitted": c.refitted,
        "localisation": [
            {
                "feature": g.name,
                "label": g.label,
                "z": g.z,
                "bins": [{"range": b.label, "n": b.n, "rms": b.rms * s} for b in g.bins],
            }
            for g in c.localisation[:5]
        ],
        "files": c.files,
    }


def write_check_json(c: ModelCheck, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(plain(check_report_dict(c), nan_as_none=True), indent=2), encoding="utf-8")
    return path


def render_check(c: ModelCheck, console: Console) -> None:
    """The terminal view: verdict and reason, the error table, where the residuals concentrate."""
    s, u = c.report_scale, c.report_unit
    colour = "green" if c.verdict == "ok" else "yellow"
    console.print(f"[bold {colour}]{c.verdict}[/]: {escape(c.reason)}", soft_wrap=True)
    t = Table(title=f"stored model on new data ({u}, {c.residual.shape[0]} samples)", title_justify="left")
    for col in ("", "value", "expected of a correct model", "noise floor"):
        t.add_column(col, justify="right" if col else "left")
    t.add_row("RMS (3-D)", f"{c.rms * s:.4f}", f"{c.expected_rms * s:.4f}", f"{c.noise_floor * s:.4f}")
    t.add_row("mean (3-D)", f"{c.mean_error * s:.4f}", "", "")
    t.add_row("max (3-D)", f"{c.max * s:.4f}", "", "")
    for i, ax in enumerate(("x", "y", "z")[: len(c.rms_axis)]):
        t.add_row(f"RMS {ax} (mean {c.mean_axis[i] * s:+.4f})", f"{c.rms_axis[i] * s:.4f}", "", "")
    t.add_row("x the noise: sqrt(chi2 / dof)", f"{c.noise.ratio:.3f}", "1", "")
    t.add_row("systematic residual (F-tests)", str(c.structure.found), "False", "")
    console.print(t)
    for name, v in c.refitted.items():
        console.print(
            f"refitted {escape(name)}: {v['stored'] * s:.4f} -> {v['value'] * s:.4f} ± {v['std'] * s:.2g} {u}",
            highlight=False,
        )
    for g in c.localisation[:3]:
        bins = ", ".join(f"{b.label}: {b.rms * s:.3f}" for b in g.bins)
        console.print(f"  RMS along {escape(g.label)} (z {g.z:.1f}): {escape(bins)}", highlight=False, soft_wrap=True)
    for name, path in c.files.items():
        console.print(f"{name}: {escape(path)}", highlight=False, soft_wrap=True)
