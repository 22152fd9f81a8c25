"""``vgr gap`` end to end on CSV: the report file, the figures, the terminal table, the exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
import yaml
from model_gap_helpers import N_SAMPLES, case

from engine.cli.main import main
from plugins.model_gap import write_gap_csv
from plugins.sim.model_gap.simulate import make_case

pytestmark = pytest.mark.timeout(300)


def campaign_csv(effects: list[tuple[str, str]], seed: int, tmp_path) -> str:
    """A simulated campaign with the hidden *effects*, written as the CSV ``vgr gap`` reads; its path."""
    return str(write_gap_csv(make_case(case(effects, seed=seed)).data, tmp_path / "x.csv"))


SCHEMA = json.loads(
    (Path(__file__).resolve().parents[2] / "plugins/model_gap/schemas/gap_report.schema.json").read_text()
)


def gap_report(folder) -> dict:
    """The report folder's gap_report.json, checked against its JSON Schema (vgr.gap_report/1)."""
    doc = json.loads((folder / "gap_report.json").read_text(encoding="utf-8"))
    jsonschema.validate(doc, SCHEMA)
    return doc


def gap_with_report(
    effects: list[tuple[str, str]], seed: int, tmp_path, exit_code: int, *extra: str
) -> tuple[str, Path, dict]:
    """``vgr gap`` on the UR5e model with a 0.05 mm noise spec and a report folder, on a simulated
    campaign with the hidden *effects* (and the *extra* options); it must exit with *exit_code*. The
    CSV's path, the report folder and its gap_report.json."""
    data = campaign_csv(effects, seed, tmp_path)
    out = tmp_path / "rep"
    argv = ["gap", "--model", "ur5e", "--data", data, "--report", str(out), "--noise-mm", "0.05", *extra]
    assert main(argv) == exit_code
    return data, out, gap_report(out)


def test_vgr_gap_on_csv_writes_the_report_plots_and_table(tmp_path, capsys):
    data, out, rep = gap_with_report([("backlash", "joint3")], 2, tmp_path, exit_code=0)
    assert rep["verdict"] == "explained"
    (eff,) = rep["effects_added"]
    assert (eff["name"], eff["where"]) == ("backlash", "joint3")
    assert set(eff) >= {"name", "where", "params", "param_std", "cv_rms_gain_mm"}
    assert eff["param_std"]["backlash_joint3"] > 0 and eff["cv_rms_gain_mm"] > 0.05
    assert rep["noise_floor_mm"] == pytest.approx(0.05 * 3**0.5)
    assert rep["rms_before_mm"] > 1.5 * rep["noise_floor_mm"]
    assert rep["rms_after_mm"] <= 1.2 * rep["noise_floor_mm"]
    assert rep["problem"]["data"]["n_samples"] == N_SAMPLES
    for name in ("gap_histograms.png", "gap_rounds.png", "gap_effect_1_backlash_joint3.png", "augmented_model.yaml"):
        assert (out / name).stat().st_size > 1000, name
        assert (out / name).read_bytes()[:4] == b"\x89PNG" or name.endswith(".yaml")
    text = capsys.readouterr().out
    assert "gap before / after (mm)" in text and "backlash@joint3" in text and "explained" in text
    # the augmented model, given back with the same data, leaves no gap
    rc = main(["gap", "--model", str(out / "augmented_model.yaml"), "--data", data, "--noise-mm", "0.05",
               "--report", str(tmp_path / "again")])  # fmt: skip
    assert rc == 0
    again = gap_report(tmp_path / "again")
    assert again["verdict"] == "no_gap" and again["effects_added"] == []


def test_without_a_noise_spec_the_noise_is_estimated_and_said_so(tmp_path, capsys):
    data = campaign_csv([("joint_compliance", "joint2")], 4, tmp_path)
    rc = main(["gap", "--model", "plugins/robot/robots/ur5e.yaml", "--data", data, "--report", str(tmp_path / "r")])
    assert rc == 0
    rep = gap_report(tmp_path / "r")
    assert rep["noise_source"] == "estimated"
    assert rep["noise_floor_mm"] == pytest.approx(0.05 * 3**0.5, rel=0.15)  # the truth: 0.0866 mm
    assert [(e["name"], e["where"]) for e in rep["effects_added"]] == [("joint_compliance", "joint2")]
    assert "estimated" in capsys.readouterr().out


def test_exit_code_1_when_a_gap_is_left_unexplained(tmp_path, capsys):
    data = campaign_csv([("backlash", "joint3")], 2, tmp_path)
    rc = main(["gap", "--model", "ur5e", "--data", data, "--noise-mm", "0.05", "--max-effects", "0", "--json"])
    assert rc == 1
    rep = json.loads(capsys.readouterr().out)
    jsonschema.validate(rep, SCHEMA)
    assert rep["verdict"] == "unexplained" and rep["effects_added"] == []


def test_a_tie_exits_3_and_its_augmented_model_closes_the_gap(tmp_path, capsys):
    """A range scale with the frame and the tool fitted (exactly a uniform robot scale): exit code 3, verdict
    ``explained_up_to_tie``, the pair one tie term in gap_report.json and in augmented_model.yaml (the
    representative with ``tied_with``); given back with the same data the model leaves no gap (exit 0).
    (With the default baseline the joint geometry is calibrated too, and it absorbs both scales.)"""
    data, out, rep = gap_with_report([("depth_scale", "camera")], 6, tmp_path, 3, "--calibrate", "frame,tool")
    assert rep["verdict"] == "explained_up_to_tie"
    (eff,) = rep["effects_added"]
    assert eff["tied"] and eff["name"] == "depth_scale|robot_scale" and eff["where"] == "sensor|robot"
    assert rep["rms_after_mm"] <= 1.2 * rep["noise_floor_mm"]
    text = capsys.readouterr().out
    assert "explained_up_to_tie" in text and "tie, not named" in text and "))" not in text
    model = yaml.safe_load((out / "augmented_model.yaml").read_text(encoding="utf-8"))
    (stored,) = model["effects"]
    assert f"{stored['name']}@{stored['where']}" == eff["representative"] and stored["tied_with"]
    rc = main(["gap", "--model", str(out / "augmented_model.yaml"), "--data", data, "--noise-mm", "0.05",
               "--calibrate", "frame,tool", "--json"])  # fmt: skip
    assert rc == 0
    again = json.loads(capsys.readouterr().out)
    assert again["verdict"] == "no_gap" and again["effects_added"] == []
    assert again["rms_before_mm"] <= 1.2 * again["noise_floor_mm"]


def test_noise_only_csv_exits_0_with_no_gap(tmp_path, capsys):
    data = campaign_csv([], 30, tmp_path)
    assert main(["gap", "--model", "ur5e", "--data", data, "--noise-mm", "0.05", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["verdict"] == "no_gap"


def test_bad_options_exit_2(tmp_path):
    data = campaign_csv([], 30, tmp_path)
    base = ["gap", "--model", "ur5e", "--data", data, "--noise-mm", "0.05"]
    assert main([*base, "--folds", "1"]) == 2
    assert main([*base, "--alpha", "0.9"]) == 2
    assert main([*base, "--calibrate", "frame,elbow"]) == 2
