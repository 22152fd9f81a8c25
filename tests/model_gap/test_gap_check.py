"""``vgr gap check``: a stored model scored on new data, refitting nothing (or the tool point).

One campaign of a realistic cell (DH errors on every joint, a tracker 3.5 m away, a hidden joint-2
compliance), split in two: the workflow fits its even samples and writes the augmented model; the
odd samples are new data from the same robot and cell.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from model_gap_helpers import FOLDS, case, families

from engine.cli.main import main
from plugins.calibration.kinematics import KinematicCalibrationConfig, calibrate_kinematics
from plugins.model_gap import analyse_gap, write_gap_csv
from plugins.model_gap.check import check_model
from plugins.model_gap.core import GapConfig, SelectionConfig
from plugins.model_gap.stored_model import load_stored_model
from plugins.robot.effects import effects_from_config
from plugins.robot.with_effects import RobotWithEffects
from plugins.sim.model_gap.simulate import make_case

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """(augmented model file, the workflow's result, data it was fitted to, new data)."""
    c = case([("joint_compliance", "joint2")], scenario="full", seed=16)
    camp = make_case(type(c)(**{**c.__dict__, "n_samples": 240}))
    old, new = camp.data.subset(np.arange(0, 240, 2)), camp.data.subset(np.arange(1, 240, 2))
    out = tmp_path_factory.mktemp("gap")
    cfg = GapConfig(SelectionConfig(cv_folds=FOLDS, seed=0))
    res = analyse_gap(camp.model, old, noise_mm=0.05, config=cfg, families=families(), report_dir=out)
    assert res.named == [("joint_compliance", "joint2")], res.reason
    return out / "augmented_model.yaml", res, old, new


def test_a_stored_model_predicts_as_the_workflow_did_and_nothing_moves(fitted):
    path, res, old, new = fitted
    stored = path.read_bytes()
    again = check_model(path, old, noise_mm=0.05, families=families())
    np.testing.assert_allclose(again.residual, res.iterations[-1].residual, rtol=0, atol=1e-10)
    chk = check_model(path, new, noise_mm=0.05, families=families())
    assert chk.verdict == "ok", chk.reason
    assert chk.refitted == {} and path.read_bytes() == stored  # nothing refitted, the file untouched
    assert chk.rms <= 1.2 * chk.expected_rms and chk.expected_factor > 1.0
    # the same prediction by another road: the simulator's effects from the file on the stored robot
    model = load_stored_model(path)
    truth = RobotWithEffects(model.robot, effects_from_config(model.effects[0]["config"]))
    pred = truth.fk(new.samples.q, new.samples.context())[:, :3, 3]
    np.testing.assert_allclose(chk.residual, new.samples.positions - pred, rtol=0, atol=1e-10)


def test_a_new_tool_is_a_gap_until_its_point_is_refitted(fitted, tmp_path, capsys):
    path, _, _, new = fitted
    robot = load_stored_model(path).robot
    moved = new.subset(np.arange(new.n_samples))
    shift = np.array([2e-3, -1e-3, 3e-3])  # the new tool's point, 3.7 mm from the old one (flange frame)
    moved.samples.positions = moved.samples.positions + robot.fk(new.samples.q)[:, :3, :3] @ shift
    data = str(write_gap_csv(moved, tmp_path / "new_tool.csv"))
    base = ["gap", "check", "--model", str(path), "--data", data, "--noise-mm", "0.05", "--json"]
    assert main(base) == 1
    rep = json.loads(capsys.readouterr().out)
    assert rep["verdict"] == "gap" and rep["residual_structure"]["found"] and rep["rms_mm"] > 3
    assert main([*base, "--refit", "tool"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["verdict"] == "ok" and rep["rms_mm"] <= 1.2 * rep["expected_rms_mm"]
    for k, axis in zip(shift, ("tx", "ty", "tz"), strict=True):
        r = rep["refitted"][f"tool.{axis}"]
        assert abs(r["value"] - r["stored"] - k) < 4 * r["std"] and r["std"] < 2e-5
    assert rep["noise_check"]["dof"] == 3 * new.n_samples - 3  # the tool point's 3 parameters


def test_bad_check_options_and_files_exit_2(fitted, tmp_path):
    path, _, _, new = fitted
    data = str(write_gap_csv(new, tmp_path / "new.csv"))
    base = ["gap", "check", "--model", str(path), "--data", data, "--noise-mm", "0.05"]
    assert main([*base, "--refit", "frame"]) == 2
    assert main([*base, "--calibrate", "frame,tool"]) == 2
    assert main(["gap", "--model", str(path), "--data", data, "--refit", "tool"]) == 2
    not_a_model = tmp_path / "x.json"
    not_a_model.write_text('{"kind": "hand_eye", "estimate": {}}', encoding="utf-8")
    assert main(["gap", "check", "--model", str(not_a_model), "--data", data]) == 2


def test_a_kinematic_calibration_result_is_scored_as_it_was_fitted(fitted, tmp_path):
    _, _, old, _ = fitted
    robot = load_stored_model("ur5e").robot
    cal = calibrate_kinematics(robot, old.samples, config=KinematicCalibrationConfig(holdout_fraction=0.0))
    result = tmp_path / "kinematics.json"
    result.write_text(cal.result.to_json(), encoding="utf-8")
    chk = check_model(result, old, families=families())  # the noise: the calibration's own
    assert chk.model["kind"] == "kinematic calibration"
    np.testing.assert_allclose(chk.residual, cal.result.residuals, rtol=0, atol=1e-10)
    p, n = len(cal.result.param_names), 3 * old.n_samples
    assert chk.expected_factor == pytest.approx(np.sqrt(1 + p / n))
    assert chk.noise.stated_sigma == pytest.approx(cal.result.metrics["sigma_position_mm"] / 1e3)


@settings(max_examples=25, deadline=None)
@given(st.dictionaries(st.sampled_from(["kind", "estimate", "metrics", "x"]), st.one_of(st.none(), st.integers(),
                       st.text(max_size=5), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))))  # fmt: skip
def test_a_json_file_that_is_not_a_calibration_result_is_refused(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("j") / "m.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(ValueError, match="not a kinematic calibration result"):
        load_stored_model(path)
