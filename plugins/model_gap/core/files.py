"""Writing a model-gap run to a report directory: ``gap_report.json`` and the figures."""

from __future__ import annotations

from pathlib import Path

from plugins.model_gap.core.interfaces import Feature
from plugins.model_gap.core.plots import plot_effect, plot_histograms, plot_rounds
from plugins.model_gap.core.report import write_json
from plugins.model_gap.core.workflow import GapResult


def write_report(result: GapResult, features: list[Feature], directory: str | Path) -> dict[str, str]:
    """Write the figures and ``gap_report.json`` into ``directory``; returns (and records) the files."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "histograms": str(plot_histograms(result, out / "gap_histograms.png")),
        "rounds": str(plot_rounds(result, features, out / "gap_rounds.png")),
    }
    n = 0
    for it in result.iterations:
        if it.added is None:
            continue
        n += 1
        p = plot_effect(result, it, out / f"gap_effect_{n}_{it.added.file_stem}.png")
        if p is not None:
            files[f"effect_{n}"] = str(p)
    for it in result.iterations:
        if it.model_file:
            files[f"model_{it.index + 1}"] = it.model_file
    files["report"] = str(out / "gap_report.json")
    result.files.update(files)
    write_json(result, out / "gap_report.json")
    return files
