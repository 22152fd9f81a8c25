"""benchmarks/handeye_streams.py's --quick path runs end to end (one trial per case, well under a
minute) and writes a result with every condition and case, its targets, and the quick mark."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "handeye_streams.py"


def _load():
    spec = importlib.util.spec_from_file_location("handeye_streams_benchmark", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # (dataclasses look their module up)
    spec.loader.exec_module(module)
    return module


def test_the_quick_run_writes_every_condition(tmp_path):
    bench = _load()
    out = tmp_path / "quick.json"
    bench.main(["--quick", "--trials", "1", "--out", str(out)])
    doc = json.loads(out.read_text())
    assert doc["quick"] is True and "not a measurement" in doc["note"]
    assert set(doc["conditions"]) == set(bench.CONDITIONS)
    n_cases = {"clock_offset": 15, "outliers": 26, "anisotropic": 4, "unknown_scale": 4, "poses": 10}
    for name, cond in doc["conditions"].items():
        assert len(cond["cases"]) == n_cases[name], name
        for case in cond["cases"]:
            assert set(case["methods"]) == set(bench.METHODS), (name, case["case"])
            assert all(s["n"] == 1 for s in case["methods"].values())
    assert {t["condition"] for t in doc["targets"]} == set(bench.CONDITIONS)
    assert all(isinstance(t["passed"], bool) for t in doc["targets"])
    clock = doc["conditions"]["clock_offset"]["cases"]
    assert all("offset_error_ms" in c["figures"] for c in clock)
    assert doc["seed"] == 11 and doc["trials"] == 1 and doc["machine"]["opencv"] and doc["wall_time_s"] > 0
