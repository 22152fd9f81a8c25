"""The ``model_gap`` stage in a recipe: the simulated cell with a hidden joint-2 compliance."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from recipe_helpers import graph_from

from engine.run.runner import Observer, Runner

pytestmark = pytest.mark.timeout(300)

RECIPE = Path(__file__).resolve().parents[2] / "recipes" / "model_gap_sim.yaml"


class Keep(Observer):
    def __init__(self) -> None:
        self.msgs: list[tuple[str, str, object]] = []

    def on_publish(self, stage, port, payload, envelope, msg):
        self.msgs.append((stage, port, msg))


def _run(overrides: list[str]):
    keep = Keep()
    summary = Runner(
        graph_from(RECIPE.read_text(encoding="utf-8"), overrides, name=str(RECIPE)), observers=[keep]
    ).run()
    return summary, [m for s, p, m in keep.msgs if (s, p) == ("gap", "result")]


@pytest.mark.slow
def test_recipe_names_the_hidden_compliance_and_writes_the_report(tmp_path):
    summary, results = _run([f"gap.report_dir={tmp_path / 'rep'}"])
    assert summary.ok, summary.stop_reason
    (res,) = results
    assert res.kind == "model_gap" and res.verdict == "explained", res.reasons
    rep = json.loads(res.result_json)
    assert [(e["name"], e["where"]) for e in rep["effects_added"]] == [("joint_compliance", "joint2")]
    assert rep["rms_after_mm"] <= 1.2 * rep["noise_floor_mm"] < rep["rms_before_mm"]
    assert res.metrics["effects_added"] == 1.0
    assert (tmp_path / "rep" / "gap_report.json").is_file()
    est, sd = compliance(rep)  # the stage's payload_kg parameter: the estimate within its sigma
    assert abs(est - TRUE_COMPLIANCE) <= sd, (est, sd)
    # the answer is printed at the end of the run: a result event with the value and its sigma
    (ev,) = [e for e in summary.events if e.level == "result" and e.code == "model_gap"]
    assert ev.message.startswith("explained: effects added: joint_compliance@joint2 (compliance_joint2 = ")
    assert " ± " in ev.message and "rad/(N m)" in ev.message and "RMS" in ev.message
    assert ev.details["files"] == {"report": str(tmp_path / "rep" / "gap_report.json")}


def test_recipe_without_the_hidden_effect_finds_no_gap():
    summary, results = _run(["robot.effects={}", "campaign.n_poses=60"])
    assert summary.ok, summary.stop_reason
    (res,) = results
    assert res.verdict == "no_gap", res.reasons


def test_too_few_poses_fail_with_a_reason_not_an_exception():
    summary, results = _run(["campaign.n_poses=5"])
    assert summary.ok, summary.stop_reason
    (res,) = results
    assert res.verdict == "failed" and "too few" in res.reasons[0]


def test_vgr_gap_reads_the_recording_of_the_recipe(tmp_path, capsys):
    """`vgr run` records the campaign; `vgr gap` on the MCAP picks the campaign's joints + readings."""
    from engine.cli.main import main

    rec = tmp_path / "run.mcap"
    assert main(["run", str(RECIPE), "--record", str(rec), "-p", "campaign.n_poses=60"]) == 0
    capsys.readouterr()
    assert main(["gap", "--model", "ur5e", "--data", str(rec), "--noise-mm", "0.05", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert "/campaign/joint_state" in rep["problem"]["data"]["source"]
    assert [(e["name"], e["where"]) for e in rep["effects_added"]] == [("joint_compliance", "joint2")]
    assert rep["rms_after_mm"] <= 1.2 * rep["noise_floor_mm"]
    # the payload the robot carried (2 kg, from the recorded recipe) loads joint 2: the compliance
    # estimate matches the truth within its own sigma
    est, sd = compliance(rep)
    assert abs(est - TRUE_COMPLIANCE) <= sd, (est, sd)
    # told there was no payload, the same data give a compliance several sigma off
    assert (
        main(["gap", "--model", "ur5e", "--data", str(rec), "--noise-mm", "0.05", "--payload-kg", "0", "--json"]) == 0
    )
    est0, sd0 = compliance(json.loads(capsys.readouterr().out))
    assert abs(est0 - TRUE_COMPLIANCE) > 3 * sd0, (est0, sd0)


TRUE_COMPLIANCE = 6.0e-6  # rad/(N m) on joint 2, recipes/model_gap_sim.yaml


def compliance(rep: dict) -> tuple[float, float]:
    (e,) = [e for e in rep["effects_added"] if e["name"] == "joint_compliance"]
    return e["params"]["compliance_joint2"], e["param_std"]["compliance_joint2"]
