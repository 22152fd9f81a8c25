"""Several measured points per pose in ``vgr gap`` and ``vgr gap check``: three reflectors on the tool,
one frame and one geometry for all, one tool point per name (a ``point`` column)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from model_gap_helpers import FOLDS, families

from engine.cli.main import main
from plugins.model_gap import analyse_gap, read_gap_csv, write_gap_csv
from plugins.model_gap.core import GapConfig, SelectionConfig
from plugins.sim.model_gap.simulate import LEVELS, REFLECTORS, HiddenCase, HiddenEffect, make_case

pytestmark = pytest.mark.timeout(300)


def test_three_points_per_pose_name_the_effect_and_the_stored_model_scores_new_poses(tmp_path, capsys):
    hidden = (HiddenEffect("joint_compliance", "joint2", LEVELS["high"]),)
    camp = make_case(HiddenCase("3pt", "single", "high", "full", hidden, 17, n_samples=120, points=3))
    data = camp.data
    assert data.samples.point_names == ("R1", "R2", "R3") and data.n_samples == 360
    fit, new = data.subset(np.arange(0, 180)), data.subset(np.arange(180, 360))  # 60 poses each
    path = write_gap_csv(fit, tmp_path / "three.csv")
    assert np.array_equal(read_gap_csv(path).samples.point, fit.samples.point)
    out = tmp_path / "rep"
    assert main(["gap", "--model", "ur5e", "--data", str(path), "--noise-mm", "0.05", "--folds", str(FOLDS),
                 "--report", str(out), "--json"]) == 0  # fmt: skip
    rep = json.loads(capsys.readouterr().out)
    assert [(e["name"], e["where"]) for e in rep["effects_added"]] == [("joint_compliance", "joint2")]
    assert {f"tool[R{k}].{a}" for k in (2, 3) for a in ("tx", "ty", "tz")} <= set(
        rep["problem"]["calibration"]["parameters"]
    )
    stored = yaml.safe_load((out / "augmented_model.yaml").read_text(encoding="utf-8"))
    offsets = {k: np.asarray(v) for k, v in stored["tool_points"].items()}
    for k, r in zip(("R2", "R3"), REFLECTORS[1:], strict=True):  # a point's offset from R1: |r_k - r_1|
        assert abs(np.linalg.norm(offsets[k]) - np.linalg.norm(r)) < 1e-4
    # the stored model (three points, the compliance) scores the other 60 poses without refitting
    new_csv = write_gap_csv(new, tmp_path / "new.csv")
    assert main(["gap", "check", "--model", str(out / "augmented_model.yaml"), "--data", str(new_csv),
                 "--json"]) == 0  # fmt: skip
    chk = json.loads(capsys.readouterr().out)
    assert chk["verdict"] == "ok" and chk["rms_mm"] <= 1.2 * chk["expected_rms_mm"]
    assert chk["noise_check"]["dof"] == 3 * 180  # nothing refitted


def test_a_point_the_stored_model_does_not_know_is_refused(tmp_path):
    camp = make_case(HiddenCase("3pt", "noise", "none", "full", (), 18, n_samples=40, points=3))
    cfg = GapConfig(SelectionConfig(cv_folds=FOLDS))
    analyse_gap(camp.model, camp.data, noise_mm=0.05, config=cfg, families=families(), report_dir=tmp_path / "r")
    other = camp.data.subset(np.arange(camp.data.n_samples))
    other.samples.point = np.char.replace(other.samples.point, "R3", "R9")
    csv = write_gap_csv(other, tmp_path / "other.csv")
    assert main(["gap", "check", "--model", str(tmp_path / "r" / "augmented_model.yaml"), "--data", str(csv)]) == 2
