"""Kinematic calibration: bad input, verdicts a user can act on, and the CSV format."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plugins.calibration.kinematics import (
    KinematicSamples,
    calibrate_kinematics,
    read_csv,
    read_json,
    read_samples,
    write_csv,
    write_json,
)
from plugins.robot.effects import GeometricErrors, JointCompliance
from plugins.robot.with_effects import RobotWithEffects

from .kincal_sim import measure, nominal_model, random_poses, true_robot

MODEL = nominal_model("ur5e")
TRUTH = true_robot("ur5e", seed=31)


def _data(n=60, seed=32, q=None):
    q = random_poses(MODEL, n, seed) if q is None else q
    return measure(TRUTH, q, seed + 1)


# --------------------------------------------------------------------------- bad input


@given(st.integers(0, 19), st.integers(0, 5), st.sampled_from([np.nan, np.inf]))
@settings(max_examples=15, deadline=None)
def test_non_finite_joints_or_positions_are_rejected(row, col, bad):
    q = random_poses(MODEL, 20, 1)
    p = np.zeros((20, 3))
    q_bad = q.copy()
    q_bad[row, col] = bad
    with pytest.raises(ValueError, match="NaN"):
        KinematicSamples(q_bad, p)
    p_bad = p.copy()
    p_bad[row, col % 3] = bad
    with pytest.raises(ValueError, match="NaN"):
        KinematicSamples(q, p_bad)


def test_shape_and_joint_count_errors():
    with pytest.raises(ValueError, match="positions"):
        KinematicSamples(np.zeros((5, 6)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="joints"):
        calibrate_kinematics(MODEL, KinematicSamples(np.zeros((5, 5)), np.zeros((5, 3))))


@given(st.floats(1.01, 2.0))
@settings(max_examples=10, deadline=None)
def test_non_orthonormal_rotations_are_rejected(scale):
    R = np.tile(np.eye(3), (4, 1, 1))
    R[2] *= scale
    with pytest.raises(ValueError, match="orthonormal"):
        KinematicSamples(np.zeros((4, 6)), np.zeros((4, 3)), R)


def test_millimetres_given_as_metres_are_detected():
    data = _data()
    with pytest.raises(ValueError, match="millimetres"):
        calibrate_kinematics(MODEL, KinematicSamples(data.q, data.positions * 1000.0))


# --------------------------------------------------------------------------- verdicts


def test_too_few_poses_is_degenerate():
    out = calibrate_kinematics(MODEL, _data(n=7), config=None)
    assert out.result.verdict == "degenerate"
    assert any("unknowns" in r or "do not excite" in r for r in out.result.reasons)
    assert not out.result.usable


def test_a_joint_that_never_moves_is_reported_with_advice():
    q = random_poses(MODEL, 60, 40)
    q[:, 4] = 0.3  # wrist 2 frozen
    out = calibrate_kinematics(MODEL, _data(q=q))
    assert out.result.verdict == "degenerate"
    reason = next(r for r in out.result.reasons if "do not excite" in r)
    assert "joint5" in reason
    assert out.result.advice


def test_duplicate_poses_are_reported():
    q = random_poses(MODEL, 50, 41)
    q = np.vstack([q, q[:5]])
    out = calibrate_kinematics(MODEL, _data(q=q))
    assert any("duplicate" in r for r in out.result.reasons)


def test_gross_outliers_are_flagged():
    data = _data(n=80, seed=42)
    data.positions[[3, 17]] += 3e-3  # two 3 mm blunders (e.g. a beam break)
    out = calibrate_kinematics(MODEL, data, holdout=_data(n=20, seed=50))
    assert out.result.verdict == "warning"
    assert set(np.flatnonzero(out.result.outliers)) == {3, 17}


def test_unmodelled_compliance_is_not_hidden():
    """A compliant shoulder the geometric model cannot explain: the verdict says so."""
    errors = TRUTH.effects[0]
    assert isinstance(errors, GeometricErrors)
    soft = RobotWithEffects(TRUTH.nominal, [errors, JointCompliance((2, 3), (2e-5, 2e-5))])
    q = random_poses(MODEL, 80, 43)
    out = calibrate_kinematics(MODEL, measure(soft, q, 44))
    assert out.result.verdict == "warning"
    assert any("exceed the stated noise" in r for r in out.result.reasons)


def test_wrong_robot_model_is_flagged_not_passed_as_ok():
    irb = nominal_model("abb_irb120")
    q = random_poses(irb, 60, 45)
    data = measure(true_robot("abb_irb120", seed=46), q, 47)
    out = calibrate_kinematics(MODEL, data)  # a UR5e model for IRB 120 data
    # generic DH parameters can even turn a UR5e into an IRB 120 (the fit itself succeeds); what
    # must not happen is an "ok": the implausible parameter moves are flagged
    assert out.result.verdict == "warning"
    assert any("beyond manufacturing tolerances" in r for r in out.result.reasons)
    assert out.result.advice


# --------------------------------------------------------------------------- CSV


def test_csv_round_trip_with_context(tmp_path):
    data = _data(n=12, seed=60)
    data.t_s = np.linspace(0, 600, 12)
    data.direction = np.where(np.random.default_rng(0).random((12, 6)) > 0.5, 1.0, -1.0)
    data.payload_kg = np.full(12, 1.5)
    data.temp_c = np.linspace(20, 25, 12)
    path = tmp_path / "data.csv"
    write_csv(data, path)
    header = path.read_text().splitlines()[0].split(",")
    assert header[:9] == [f"q{i}_deg" for i in range(1, 7)] + ["x_mm", "y_mm", "z_mm"]
    back = read_csv(path)
    assert np.allclose(back.q, data.q, atol=1e-12) and np.allclose(back.positions, data.positions, atol=1e-12)
    for name in ("t_s", "direction", "payload_kg", "temp_c"):
        assert np.allclose(getattr(back, name), getattr(data, name))
    pose = measure(TRUTH, data.q, 61, rot_noise_rad=1e-4)
    write_csv(pose, tmp_path / "pose.csv")
    assert np.allclose(read_csv(tmp_path / "pose.csv").rotations, pose.rotations, atol=1e-12)


def test_json_form_has_the_csv_columns_and_round_trips(tmp_path):
    data = measure(TRUTH, random_poses(MODEL, 12, 63), 64, rot_noise_rad=1e-4)
    data.temp_c = np.linspace(20, 25, 12)
    write_json(data, tmp_path / "d.json")
    write_csv(data, tmp_path / "d.csv")
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["format"] == "vgr.kinematic.samples/1" and len(doc["samples"]) == 12
    assert list(doc["samples"][0]) == (tmp_path / "d.csv").read_text().splitlines()[0].split(",")
    for back in (read_json(tmp_path / "d.json"), read_samples(tmp_path / "d.json")):
        assert np.allclose(back.q, data.q, atol=1e-12) and np.allclose(back.positions, data.positions, atol=1e-12)
        assert np.allclose(back.rotations, data.rotations, atol=1e-12) and np.allclose(back.temp_c, data.temp_c)
    (tmp_path / "bare.json").write_text(json.dumps(doc["samples"]))  # a bare list of poses
    assert np.allclose(read_json(tmp_path / "bare.json").q, data.q, atol=1e-12)
    # the same checks as the CSV: units, missing fields, other formats
    rows = [dict(r, x_mm=r["x_mm"] / 1000, y_mm=r["y_mm"] / 1000, z_mm=r["z_mm"] / 1000) for r in doc["samples"]]
    (tmp_path / "m.json").write_text(json.dumps(rows))
    with pytest.raises(ValueError, match="look like metres"):
        read_json(tmp_path / "m.json")
    del doc["samples"][3]["q2_deg"]
    (tmp_path / "gap.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="pose 3 has no field 'q2_deg'"):
        read_json(tmp_path / "gap.json")
    (tmp_path / "other.json").write_text(json.dumps({"format": "vgr.handeye.samples/1", "samples": []}))
    with pytest.raises(ValueError, match=r"is not 'vgr\.kinematic\.samples/1'"):
        read_json(tmp_path / "other.json")


def test_csv_unit_and_format_errors(tmp_path):
    data = _data(n=12, seed=62)
    path = tmp_path / "m.csv"
    write_csv(KinematicSamples(data.q, data.positions / 1000.0), path)  # metres in the mm columns
    with pytest.raises(ValueError, match="look like metres"):
        read_csv(path)
    write_csv(KinematicSamples(np.radians(data.q), data.positions), path)  # radians in the deg columns
    assert any("radians" in w for w in read_csv(path).check())
    path.write_text("q1_deg,q2_deg,x_mm,y_mm\n1,2,3,4\n")
    with pytest.raises(ValueError, match="z_mm"):
        read_csv(path)
    path.write_text("q1_deg,q3_deg,x_mm,y_mm,z_mm\n1,2,300,400,500\n")
    with pytest.raises(ValueError, match=r"q1_deg \.\. qN_deg"):
        read_csv(path)
    path.write_text("q1_deg,x_mm,y_mm,z_mm\n1,300,abc,500\n")
    with pytest.raises(ValueError, match="y_mm"):
        read_csv(path)
    with pytest.raises(ValueError, match="does not exist"):
        read_csv(tmp_path / "nope.csv")
