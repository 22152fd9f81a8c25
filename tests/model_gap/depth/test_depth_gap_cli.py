"""``vgr gap --depth CAPTURES`` end to end: the report document against its JSON Schema (strict JSON
on stdout and on disk), the exit codes (the robot ``vgr gap``'s table: 0 explained or no gap, 1
unexplained, 3 a tie), the terminal report, a stated noise law from the command line, and options
of the other workflows refused with exit code 2."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from depth_gap_helpers import add_range_error, invalid, run_json

from engine.cli.main import main
from plugins.model_gap.cli import EXIT_CODES
from plugins.model_gap.depth.data import DepthFrame
from plugins.model_gap.depth.inputs import write_captures
from plugins.model_gap.depth.report import VERDICT_EXIT_CODES, schema
from plugins.sim.model_gap.depth_captures import simulate_captures

SCHEMA = schema()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Captures files: a hidden quadratic range error with flying pixels, nothing hidden, a step in
    range (outside the catalog), one distance of a small target (a tie)."""
    folder = tmp_path_factory.mktemp("depth_gap")
    tie = simulate_captures("range_bias", seed=1, near_m=0.78, far_m=0.8, max_tilt_deg=3)
    tie.frames = [DepthFrame(f.name, f.depth, f.T_cam_target, (-0.06, 0.06, -0.06, 0.06)) for f in tie.frames]
    sets = {
        "quadratic": simulate_captures("range_quadratic", seed=3, outlier_fraction=0.02),
        "none": simulate_captures(None, seed=3),
        "step": add_range_error(simulate_captures(None, seed=4), lambda r, x, y: np.where(r > 0.8, 2e-3, 0.0)),
        "tie": tie,
    }
    out = {}
    for name, caps in sets.items():
        out[name] = str(folder / f"{name}.npz")
        write_captures(out[name], caps)
    return out


def test_the_exit_codes_are_the_robot_gaps():
    assert VERDICT_EXIT_CODES == EXIT_CODES


def test_a_hidden_quadratic_is_named_in_a_report_that_follows_its_schema(files, capsys, tmp_path):
    code, doc = run_json(capsys, "--depth", files["quadratic"], "--report", str(tmp_path / "r"))
    jsonschema.validate(doc, SCHEMA)
    assert code == 0 and doc["exit_code"] == 0 and doc["verdict"] == "explained", doc["reason"]
    assert doc["named"] == ["range_quadratic"] and doc["target"] == "known"
    (added,) = doc["effects_added"]
    assert added["coefficients"]["quad_mm_per_m2"] == pytest.approx(2.5, abs=0.3) and added["unit"] == "mm/m^2"
    assert doc["heldout_rms_after_mm"] < 0.6 * doc["heldout_rms_before_mm"]
    assert doc["gross_errors"]["n_flagged"] == sum(c["n_flagged"] for c in doc["captures"]) == 16 * 96
    on_disk = json.loads((tmp_path / "r" / "depth_gap_report.json").read_text())
    jsonschema.validate(on_disk, SCHEMA)
    assert on_disk["files"]["captures"].endswith("captures.npz")
    assert on_disk == doc  # stdout and the file are one document (its files listed in both)
    code, again = run_json(capsys, "--depth", on_disk["files"]["captures"])  # what the report kept re-runs alike
    assert code == 0 and again["named"] == doc["named"]


def test_nothing_hidden_exits_0_with_no_gap_and_the_terminal_says_so(files, capsys):
    code = main(["gap", "--depth", files["none"]])
    out = capsys.readouterr().out
    assert code == 0 and "verdict: no_gap" in out and "held-out range RMS" in out


def test_an_error_outside_the_catalog_exits_1_and_a_tie_exits_3(files, capsys):
    code, doc = run_json(capsys, "--depth", files["step"])
    jsonschema.validate(doc, SCHEMA)
    assert code == 1 and doc["verdict"] == "unexplained" and "fixed in range" in doc["reason"]
    assert all(e["share"] is not None for e in doc["effects_added"])
    code, doc = run_json(capsys, "--depth", files["tie"])
    jsonschema.validate(doc, SCHEMA)
    assert code == 3 and doc["verdict"] == "explained_up_to_tie" and doc["named"] == []
    assert doc["effects_added"][0]["tied"] and "range_bias" in doc["effects_added"][0]["members"]


def test_a_stated_noise_law_from_the_command_line_is_checked(files, capsys):
    code, doc = run_json(capsys, "--depth", files["none"], "--noise-mm", "0.2", "--noise-mm-per-m2", "1.0")
    assert code == 0 and doc["noise"]["stated_law"] == {"sigma_const_mm": 0.2, "sigma_quad_per_m_mm": 1.0}
    assert doc["noise"]["rms_over_stated"] == pytest.approx(1.0, abs=0.05)
    code, doc = run_json(capsys, "--depth", files["none"], "--noise-mm", "0.05", "--noise-mm-per-m2", "0.2")
    assert code == 1 and "the stated noise" in doc["reason"]


def test_the_plane_fitted_per_capture_is_said(files, capsys):
    code, doc = run_json(capsys, "--depth", files["none"], "--target", "fit")
    jsonschema.validate(doc, SCHEMA)
    assert code == 0 and doc["target"] == "fit" and doc["untested"][0]["effect"] == "range_scale"


def test_options_of_the_other_workflows_are_refused(files, capsys):
    f = files["none"]
    assert "--model" in invalid(capsys, "--depth", f, "--model", "ur5e")["error"]
    assert "--camera" in invalid(capsys, "--depth", f, "--camera", f)["error"]
    assert "--board" in invalid(capsys, "--depth", f, "--board", "chessboard:9x6:20mm")["error"]
    assert "--folds" in invalid(capsys, "--depth", f, "--folds", "1")["error"]
    assert "--noise-mm" in invalid(capsys, "--depth", f, "--noise-mm", "-1")["error"]
    assert (
        "contradicts --target fit" in invalid(capsys, "--depth", f, "--target", "fit", "--target-frame", "x")["error"]
    )
    assert (
        "options of the depth gap" in invalid(capsys, "--model", "ur5e", "--data", "x.csv", "--target", "fit")["error"]
    )
    assert "--depth CAPTURES" in invalid(capsys, "--report", "x")["error"]
