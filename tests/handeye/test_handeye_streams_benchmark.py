"""benchmarks/handeye_streams.py's --quick path runs end to end (one trial per case, well under a
minute) and writes a result with every condition and case, its targets, and the quick mark."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

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
    n_cases = {"clock_offset": 15, "outliers": 26, "anisotropic": 6, "unknown_scale": 4, "poses": 10}
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


def test_one_condition_runs_alone_and_replaces_only_its_entries(tmp_path):
    """``--condition anisotropic``: only that condition runs; into an existing result file its cases
    and targets replace the old ones and the other conditions stay (``partial_runs`` says so). The
    per-sample covariance cases carry vgr without the covariances beside it."""
    bench = _load()
    out = tmp_path / "r.json"
    old = {
        "seed": 11, "trials": 1, "quick": True, "conditions": {"poses": {"cases": ["kept"]}, "anisotropic": {}},
        "targets": [{"condition": "poses", "passed": True}, {"condition": "anisotropic", "passed": False}],
    }  # fmt: skip
    out.write_text(json.dumps(old))
    bench.main(["--quick", "--trials", "1", "--condition", "anisotropic", "--out", str(out)])
    doc = json.loads(out.read_text())
    assert doc["conditions"]["poses"] == {"cases": ["kept"]}
    cases = doc["conditions"]["anisotropic"]["cases"]
    assert len(cases) == 6 and {"condition": "anisotropic", "passed": False} not in doc["targets"]
    cov = [c for c in cases if c["case"].startswith(bench.COVARIANCE_CASE)]
    assert len(cov) == 2 and all(c["vgr_without_covariances"]["errors"]["n"] == 1 for c in cov)
    assert doc["targets_summary"]["poses"] == {"passed": 1, "of": 1}
    assert doc["partial_runs"][0]["conditions"] == ["anisotropic"]
    old["seed"] = 12
    out.write_text(json.dumps(old))
    with pytest.raises(SystemExit, match="seed"):
        bench.main(["--quick", "--trials", "1", "--condition", "anisotropic", "--out", str(out)])
