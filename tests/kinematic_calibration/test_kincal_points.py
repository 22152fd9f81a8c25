"""Several measured points per pose (a laser tracker with three reflectors on the tool).

One frame and one geometry for all, one tool point per name: fitted together the three points equal
the truth within the reported covariance. The reference is the calibration of the noise-free data
(the "identifiable truth": a rotation of every point about the last joint axis is the last joint's
zero, so the points' flange coordinates are known up to it), and the reflectors' distances, which
no such rotation changes, are compared with the true ones directly.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from engine.cli.main import main
from plugins.calibration.kinematics import (
    KinematicCalibrationConfig,
    KinematicSamples,
    calibrate_kinematics,
    read_csv,
    write_csv,
)

from .kincal_sim import NOISE_M, nominal_model, random_poses, true_robot

REFLECTORS = {"A": (0.0, 0.0, 0.0), "B": (0.05, 0.0, 0.0), "C": (0.0, 0.04, 0.02)}  # TCP frame, m


def _three_points(robot, q: np.ndarray, noise_seed: int | None) -> KinematicSamples:
    rows = np.repeat(np.arange(len(q)), 3)
    names = np.tile(np.array(list(REFLECTORS)), len(q))
    T = robot.fk(q)[rows]
    r = np.array([REFLECTORS[n] for n in names])
    p = np.einsum("nij,nj->ni", T[:, :3, :3], r) + T[:, :3, 3]
    if noise_seed is not None:
        p = p + np.random.default_rng(noise_seed).normal(0.0, NOISE_M, p.shape)
    return KinematicSamples(q[rows], p, point=names)


def _state(out, names: list[str]) -> np.ndarray:
    v = dict(zip(out.model.param_names, out.model.param_values, strict=True))
    v |= dict(zip(out.points.param_names(), out.points.flat(), strict=True))
    return np.array([v[n] for n in names])


def test_three_points_per_pose_fitted_together_equal_the_truth_within_covariance():
    truth = true_robot("ur5e", seed=31)
    model = nominal_model("ur5e")
    q = random_poses(model, 60, seed=32)
    cfg = KinematicCalibrationConfig(holdout_fraction=0.0)
    ref = calibrate_kinematics(model, _three_points(truth, q, None), config=cfg)
    assert ref.result.metrics["rms_after_mm"] < 1e-6  # one frame and geometry, three tool points: the truth
    point_params = {f"tool[{k}].{a}" for k in "BC" for a in ("tx", "ty", "tz")}
    assert point_params <= set(ref.result.param_names)
    out = calibrate_kinematics(model, _three_points(truth, q, 33), config=cfg)
    assert out.result.verdict == "ok" and out.result.param_names == ref.result.param_names
    names = [n for n in out.result.param_names if not n.startswith("base.")]
    sel = [out.result.param_names.index(n) for n in names]
    cov = out.result.covariance[np.ix_(sel, sel)]
    e = _state(out, names) - _state(ref, names)
    nu = out.result.metrics["covariance_dof"]
    assert nu == 3 * 180 - len(out.result.param_names)
    assert e @ np.linalg.solve(cov, e) / len(names) <= stats.f.ppf(0.999, len(names), nu)
    # the reflectors' distances, straight from the truth
    pts = {k: np.asarray(v) for k, v in out.result.estimate["tool_points"].items()}
    assert set(pts) == set(REFLECTORS)
    for a, b in (("A", "B"), ("A", "C"), ("B", "C")):
        d = pts[b] - pts[a]
        grad = np.zeros(len(names))  # the distance's gradient w.r.t. the point offsets (A's offset is 0)
        for k, sign in ((b, 1.0), (a, -1.0)):
            if k != "A":
                grad[[names.index(f"tool[{k}].{x}") for x in ("tx", "ty", "tz")]] += sign * d / np.linalg.norm(d)
        sd = float(np.sqrt(grad @ cov @ grad))
        true = float(np.linalg.norm(np.subtract(REFLECTORS[b], REFLECTORS[a])))
        assert abs(np.linalg.norm(d) - true) < 4 * sd and sd < 3e-5, (a, b, np.linalg.norm(d), true, sd)


def test_the_point_column_round_trips_and_vgr_calibrate_kinematics_fits_every_point(tmp_path, capsys):
    truth = true_robot("ur5e", seed=34)
    q = random_poses(nominal_model("ur5e"), 40, seed=35)
    samples = _three_points(truth, q, 36)
    path = tmp_path / "three.csv"
    write_csv(samples, path)
    back = read_csv(path)
    assert back.point_names == ("A", "B", "C") and np.array_equal(back.point, samples.point)
    assert not any("duplicate" in w for w in back.check())  # three points at one pose are not duplicates
    out = tmp_path / "cal.json"
    assert main(["calibrate", "kinematics", str(path), "--json", str(out), "--tool-mm", "0", "0", "100"]) == 0
    assert "tool[C].tz" in out.read_text(encoding="utf-8") and "tool_points" in out.read_text(encoding="utf-8")


@settings(max_examples=30, deadline=None)
@given(st.lists(st.sampled_from(["A", "B", "", " ", "\t"]), min_size=4, max_size=4))
def test_an_empty_point_name_is_refused(names):
    q, p = np.zeros((4, 6)), np.ones((4, 3))
    if all(n.strip() for n in names):
        assert KinematicSamples(q, p, point=np.array(names)).point_names == tuple(dict.fromkeys(names))
    else:
        with pytest.raises(ValueError, match="point is empty"):
            KinematicSamples(q, p, point=np.array(names))
