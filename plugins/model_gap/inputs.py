"""Model-gap input by file type: a kinematic CSV (plugins.model_gap.data) or a vgr recording
(plugins.model_gap.recordings)."""

from __future__ import annotations

from pathlib import Path

from plugins.model_gap.data import GapData, GapDataError, read_gap_csv, with_payload
from plugins.model_gap.recordings import read_gap_mcap


def load_gap_data(path: str | Path, *, payload_kg: float | None = None, **kw) -> GapData:
    """CSV or MCAP by file suffix. *payload_kg* (kg at the TCP, every sample) replaces what a
    recording's recipe says; a CSV with a ``payload_kg`` column keeps its own and refuses it."""
    p = Path(path)
    if p.suffix.lower() == ".mcap":
        opts = {k: v for k, v in kw.items() if k in ("joint_topic", "measurement_topic")}
        return read_gap_mcap(p, payload_kg=payload_kg, **opts)
    if p.suffix.lower() in (".csv", ".txt"):
        data = read_gap_csv(p, **{k: v for k, v in kw.items() if k == "sensor"})
        return data if payload_kg is None else with_payload(data, payload_kg)
    raise GapDataError(f"{p}: unknown data format {p.suffix!r}; give a .csv file or a .mcap recording")
