"""``guidance_report``: the run summary a technician reads after a guidance + docking run.

A sink wired to a guidance stage's ``result`` and the docking stage's ``correction``. For each job
it writes, in its folder of the run folder (``runs/<run>/<stage>/``, or ``report_dir``: see
engine/run_folder.py):

* ``job<k>.json``: verdicts, residual per look (mm, deg), moves, the correction the guidance found
  (T_start -> T_end) and the docking correction;
* ``job<k>.png``: the convergence plot (residual per look against the tolerances, log scale);

and raises a ``result`` event whose text is the table ``vgr run`` prints at the end.
"""

from __future__ import annotations

import json
from collections import deque
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from engine.messages import Correction
from engine.stage import Stage, StageParams
from plugins.actions import guidance_math as gm
from plugins.actions.messages import GuidanceResult
from plugins.actions.stages.guidance import Guidance


def report_dict(g: GuidanceResult, c: Correction | None) -> dict[str, Any]:
    """The JSON report of one job: guidance outcome and what docking made of it."""
    t, r = gm.correction_between(g.T_start, g.T_end)
    doc: dict[str, Any] = {
        "job": g.job,
        "mode": g.mode,
        "guidance_verdict": g.verdict,
        "guidance_reasons": list(g.reasons),
        "moves": g.moves,
        "looks": [
            {"residual_mm": m, "residual_deg": d, "match": v}
            for m, d, v in zip(g.residual_mm, g.residual_deg, g.match_verdicts, strict=False)
        ],
        "guidance_correction_mm": t * 1e3,
        "guidance_correction_deg": float(np.degrees(r)),
        "T_start": np.asarray(g.T_start).tolist(),
        "T_end": np.asarray(g.T_end).tolist(),
    }
    if c is not None:
        doc["docking_verdict"] = c.verdict
        doc["docking_reasons"] = list(c.reasons)
        doc["T_install_corrected"] = np.asarray(c.T).tolist() if c.verdict == "ok" else None
    return doc


def report_text(doc: dict[str, Any], tol_mm: float, tol_deg: float) -> str:
    """Plain-text table of *doc* (what the terminal shows)."""
    lines = [
        f"{doc['mode']} guidance job {doc['job']}: {doc['guidance_verdict']} after {doc['moves']} move(s)",
        f"  {'look':>4}  {'residual mm':>12}  {'residual deg':>12}  match",
    ]
    for k, look in enumerate(doc["looks"]):
        ok = look["residual_mm"] <= tol_mm and look["residual_deg"] <= tol_deg
        lines.append(
            f"  {k:>4}  {look['residual_mm']:>12.4f}  {look['residual_deg']:>12.4f}  {look['match']}"
            + ("  (within tolerance)" if ok else "")
        )
    lines.append(
        f"  correction found: {doc['guidance_correction_mm']:.3f} mm / {doc['guidance_correction_deg']:.3f} deg"
        f" (tolerance {tol_mm} mm / {tol_deg} deg)"
    )
    for reason in doc["guidance_reasons"]:
        lines.append(f"  reason: {reason}")
    if "docking_verdict" in doc:
        verdict = doc["docking_verdict"]
        lines.append(f"  docking: {'done' if verdict == 'ok' else verdict}")
        lines.extend(f"  docking reason: {r}" for r in doc["docking_reasons"])
    return "\n".join(lines)


def plot_convergence(doc: dict[str, Any], tol_mm: float, tol_deg: float, path: Path) -> None:
    """Residual per look (log scale) with the tolerances: the PNG of the report."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    looks = np.arange(len(doc["looks"]))
    mm = [max(x["residual_mm"], 1e-5) for x in doc["looks"]]
    deg = [max(x["residual_deg"], 1e-6) for x in doc["looks"]]
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2), constrained_layout=True)
    for ax, values, tol, unit in ((axes[0], mm, tol_mm, "mm"), (axes[1], deg, tol_deg, "deg")):
        ax.semilogy(looks, values, "o-")
        ax.axhline(tol, color="tab:green", linestyle="--", label=f"tolerance {tol} {unit}")
        ax.set_xlabel("look (0 = first capture)")
        ax.set_ylabel(f"residual {unit}")
        ax.set_xticks(looks)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right")
    fig.suptitle(f"{doc['mode']} guidance job {doc['job']}: {doc['guidance_verdict']}")
    fig.savefig(path, dpi=100)
    plt.close(fig)


class GuidanceReport(Stage):
    """Table, JSON and convergence PNG for each guidance job (and its docking outcome)."""

    type_name = "guidance_report"
    role = "sink"
    inputs: ClassVar = {"guidance": GuidanceResult, "correction": Correction}

    class Params(StageParams):
        report_dir: str | None = Field(
            None, description="folder for the JSON and PNG files (default: the stage's folder in the run folder)"
        )
        translation_tol_mm: float | None = Field(
            None, gt=0.0, description="tolerance drawn on the plot; default: the one guidance used"
        )
        rotation_tol_deg: float | None = Field(None, gt=0.0)
        plot: bool = True

    def setup(self) -> None:
        self.guidance: deque[GuidanceResult] = deque()
        self.corrections: deque[Correction] = deque()

    def on_message(self, port: str, msg: Any) -> None:
        (self.guidance if port == "guidance" else self.corrections).append(msg)
        while self.guidance and self.corrections:
            self._report(self.guidance.popleft(), self.corrections.popleft())

    def finish(self) -> None:
        while self.guidance:  # docking never answered (its input ended): report the guidance alone
            self._report(self.guidance.popleft(), None)

    def _report(self, g: GuidanceResult, c: Correction | None) -> None:
        p: GuidanceReport.Params = self.params  # type: ignore[assignment]
        doc = report_dict(g, c)
        folder = self.ctx.output_dir(p.report_dir)
        stem = folder / f"job{g.job}" if folder is not None else None
        files: dict[str, str] = {}
        if stem is not None:
            files["report"] = str(stem.with_suffix(".json"))
            stem.with_suffix(".json").write_text(json.dumps(doc, indent=2))
        # the tolerances guidance converged against (a result from before they travelled: its defaults)
        defaults = Guidance.Params.model_fields
        tol_mm = p.translation_tol_mm or g.translation_tol_mm or defaults["translation_tol_mm"].default
        tol_deg = p.rotation_tol_deg or g.rotation_tol_deg or defaults["rotation_tol_deg"].default
        if stem is not None and p.plot and doc["looks"]:
            plot_convergence(doc, tol_mm, tol_deg, stem.with_suffix(".png"))
            files["convergence plot"] = str(stem.with_suffix(".png"))
        text = report_text(doc, tol_mm, tol_deg)
        self.ctx.event("result", "guidance_report", text, files=files, job=g.job)
