"""`vgr calibrate`: real MoveIt data (hand-eye, robot-world, TCP), simulated files (Vive, kinematics),
reports, and exit codes: 0 usable, 1 degenerate / failed, 2 bad input with a clear message."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from calib_helpers import MOVEIT, MOVEIT_T_BASE_CAM_M, RECIPES, mahalanobis2, run
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2
from scipy.stats import f as f_dist
from usable_verdicts import USABLE

from engine.cli.main import main
from engine.transforms import log_so3
from plugins.calibration.handeye import simulate as he_sim
from plugins.calibration.handeye.io import load_pose_pairs, write_pose_pairs_json
from plugins.calibration.kinematics import write_csv, write_json
from plugins.calibration.tcp_camera import TcpCameraData, TcpNoiseModel, save_tcp_json
from plugins.calibration.vive_desk import save_vive_csv, save_vive_json
from plugins.calibration.vive_desk.realtime import desktop_tcp
from plugins.calibration.vive_desk.simulate import (
    SEED_POINTS_3,
    SEED_POINTS_4,
    simulate_contacts,
    tilted_fixture_orientations,
)

pytestmark = pytest.mark.timeout(300)


def calibrate(*args: object) -> int:
    return main(["calibrate", *(str(a) for a in args)])


def within_one_percent(t: np.ndarray) -> bool:
    return bool(np.all(np.abs(np.asarray(t) - MOVEIT_T_BASE_CAM_M) <= 0.01 * np.abs(MOVEIT_T_BASE_CAM_M)))


# --------------------------------------------------------------------------- real data


@pytest.mark.parametrize("kind", ["handeye", "robot-world"])
def test_moveit_eye_to_hand_within_one_percent_with_report(kind, tmp_path, capsys):
    out = tmp_path / "report"
    # usable with a warning (exit 3): the pose-chain spread of this real data set is large
    assert calibrate(kind, MOVEIT, "--setup", "eye_to_hand", "--report", out, "--json", tmp_path / "r.json") == 3
    text = capsys.readouterr().out
    assert "verdict WARNING" in text and "pose-chain spread" in text and "per-sample residuals" in text
    res = json.loads((out / "result.json").read_text())
    assert res == json.loads((tmp_path / "r.json").read_text())
    assert within_one_percent(np.asarray(res["estimate"]["T_base_cam"])[:3, 3])
    md = (out / "summary.md").read_text()
    assert "**Verdict: warning**" in md and "| T_base_cam.x | 659." in md and "| mm |" in md
    assert (out / "report.txt").read_text().strip() == text.strip().rsplit("\nreport:", 1)[0].strip()


def test_moveit_data_as_tcp_by_camera(tmp_path, capsys):
    s = load_pose_pairs(MOVEIT)  # the marker origin seen by the fixed camera is the "TCP" point
    path = tmp_path / "tcp.json"
    save_tcp_json(
        TcpCameraData.from_marker_poses(s.T_base_tcp, s.T_cam_target, noise=TcpNoiseModel((2.6e-3,) * 3)), path
    )
    code = calibrate("tcp", path, "--json", tmp_path / "r.json")
    res = json.loads((tmp_path / "r.json").read_text())
    assert (code, res["verdict"]) in USABLE
    assert within_one_percent(np.asarray(res["estimate"]["T_base_cam"])[:3, 3])
    text = capsys.readouterr().out
    assert "tcp-camera calibration: verdict" in text and "p_flange_tcp.x" in text and "1 sigma" in text


# --------------------------------------------------------------------------- simulated files


def _vive(points=SEED_POINTS_4, orientations=3, seed=1):
    R = tilted_fixture_orientations(30.0)[:orientations]
    P = np.vstack([points] * orientations)
    return simulate_contacts(P, seed=seed, R_desktop_tcp=np.repeat(R, len(points), axis=0))


@pytest.mark.parametrize("fmt", ["json", "csv"])
def test_vive_desk_from_a_file_recovers_the_truth(fmt, tmp_path, capsys):
    sim = _vive()
    path = tmp_path / f"contacts.{fmt}"
    (save_vive_json if fmt == "json" else save_vive_csv)(sim.data, path)
    code = calibrate("vive-desk", path, "--json", tmp_path / "r.json")
    res = json.loads((tmp_path / "r.json").read_text())
    assert (code, res["verdict"]) in USABLE
    err = []
    for name, truth in (("T_base_desktop", sim.T_base_desktop), ("T_tracker_tcp", sim.T_tracker_tcp)):
        est = np.asarray(res["estimate"][name])
        err += [*(truth[:3, 3] - est[:3, 3]), *log_so3(truth[:3, :3] @ est[:3, :3].T)]
    assert mahalanobis2(np.array(err), np.asarray(res["covariance"])) < chi2.ppf(0.999, 12)
    assert "T_tracker_tcp.rotvec_z" in capsys.readouterr().out


def test_kinematics_from_a_csv_with_held_out_file(tmp_path, capsys):
    from engine.transforms import T_from_Rt
    from plugins.calibration.kinematics import KinematicSamples
    from plugins.robot.effects import GeometricErrors
    from plugins.robot.model_file import load_robot_model
    from plugins.robot.with_effects import RobotWithEffects

    nominal = load_robot_model("ur5e")
    reflector = T_from_Rt(np.eye(3), (0.03, -0.02, 0.12))  # off the last joint's axis, as a real SMR mount
    truth = RobotWithEffects(
        nominal.with_tool(reflector), [GeometricErrors(("joint2.a", "joint3.alpha"), (3e-4, 2e-4))]
    )
    rng = np.random.default_rng(4)

    def samples(n: int) -> KinematicSamples:
        q = rng.uniform(-np.pi, np.pi, (n, 6))
        return KinematicSamples(q, truth.fk(q)[:, :3, 3] + rng.normal(0, 5e-5, (n, 3)))

    cal, hold = samples(60), samples(40)
    write_csv(cal, tmp_path / "cal.csv")
    write_json(hold, tmp_path / "hold.json")  # the JSON form: same columns as fields
    out = tmp_path / "rep"
    assert calibrate("kinematics", tmp_path / "cal.csv", "--holdout", tmp_path / "hold.json", "--report", out) == 0
    text = capsys.readouterr().out
    assert "kinematic calibration: verdict OK" in text and "held-out" in text and "expected for a correct model" in text
    res = json.loads((out / "result.json").read_text())
    m = res["metrics"]
    # held-out RMS against its expected value for a correct model (noise floor raised by the fit's own
    # uncertainty, about sqrt(1 + p/n)): (after / expected)^2 ~ F(dof, nu), two-sided 99.9 %
    lo, hi = f_dist.ppf([0.0005, 0.9995], m["holdout_rms_dof"], m["covariance_dof"])
    assert lo <= (m["holdout_rms_after_mm"] / m["holdout_rms_expected_mm"]) ** 2 <= hi
    assert m["holdout_rms_expected_mm"] / (math.sqrt(3) * m["sigma_position_mm"]) < math.sqrt(1 + 2 * 27 / 180)
    assert (out / "convergence.png").stat().st_size > 10_000 and (out / "before_after.txt").is_file()
    # the calibration data as JSON give the same result
    write_json(cal, tmp_path / "cal.json")
    assert (
        calibrate(
            "kinematics", tmp_path / "cal.json", "--holdout", tmp_path / "hold.json", "--json", tmp_path / "j.json"
        )
        == 0
    )
    capsys.readouterr()
    assert json.loads((tmp_path / "j.json").read_text())["estimate"]["offsets"] == pytest.approx(
        res["estimate"]["offsets"], abs=1e-9
    )


# --------------------------------------------------------------------------- exit code 1


def test_degenerate_data_exit_one(tmp_path, capsys):
    scene = he_sim.viewing_scene(np.random.default_rng(30), 12, "eye_in_hand", max_tilt_deg=0.0, max_roll_deg=60.0)
    write_pose_pairs_json(tmp_path / "rolls.json", scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand")
    assert calibrate("handeye", tmp_path / "rolls.json") == 1
    text = capsys.readouterr().out
    assert "verdict DEGENERATE" in text and "advice:" in text
    save_vive_json(_vive(orientations=1).data, tmp_path / "one.json")
    assert calibrate("vive-desk", tmp_path / "one.json") == 1
    text = capsys.readouterr().out
    assert "verdict DEGENERATE (NOT usable" in text and "two more fixture orientations" in text
    assert calibrate("handeye", MOVEIT, "--setup", "eye_in_hand", "--no-samples") == 1  # wrong set-up: failed


def test_seed_001_protocol_says_what_to_add_and_a_cad_prior_makes_it_usable(tmp_path, capsys):
    """Seed 001 as written (3 contact points, one fixture orientation) cannot determine the lever arm:
    the advice names both remedies in words a user can act on, and the second one works from the CLI."""
    sim = simulate_contacts(SEED_POINTS_3, seed=1)
    save_vive_json(sim.data, tmp_path / "seed001.json")
    assert calibrate("vive-desk", tmp_path / "seed001.json", "--no-samples") == 1
    advice = capsys.readouterr().out.split("advice:", 1)[1]
    assert "one fixture orientation cannot determine the tracker-to-TCP lever arm" in advice
    assert "two more fixture orientations" in advice and "--tcp-prior-mm X Y Z" in advice
    cad_mm = sim.T_tracker_tcp[:3, 3] * 1e3 + np.array([0.5, -0.5, 0.3])  # a CAD value, 0.5 mm off
    code = calibrate(
        "vive-desk", tmp_path / "seed001.json", "--no-samples", "--tcp-prior-mm", *cad_mm, "--json", tmp_path / "r.json"
    )
    text = capsys.readouterr().out
    assert "note: lever-arm prior" in text and "verdict DEGENERATE" not in text
    res = json.loads((tmp_path / "r.json").read_text())
    assert (code, res["verdict"]) in USABLE
    est = {k: np.asarray(v) for k, v in res["estimate"].items()}
    # the lever arm comes from the prior here (one orientation cannot tell it): check what the contacts
    # do determine, the TCP pose in the desk frame at the calibration orientation (the prior alone,
    # with the desk frame at identity, would be metres off)
    T_cal = sim.T_base_tracker_true[0]
    got = desktop_tcp(T_cal, est["T_base_desktop"], est["T_tracker_tcp"])
    true = desktop_tcp(T_cal, sim.T_base_desktop, sim.T_tracker_tcp)
    assert np.linalg.norm(got[:3, 3] - true[:3, 3]) < 2.5e-3
    assert calibrate("vive-desk", tmp_path / "seed001.json", "--tcp-prior-mm", 0, 0, 0, "--tcp-prior-sigma-mm", 0) == 2


def test_an_unusable_result_never_replaces_a_calibration_in_use(tmp_path, capsys):
    """--json OUT may be the file a calibration_file stage loads: a later, unusable calibration (here
    the seed-001 protocol without a lever-arm prior: degenerate) goes beside it, not over it."""
    sim = simulate_contacts(SEED_POINTS_3, seed=1)
    data = tmp_path / "seed001.json"
    save_vive_json(sim.data, data)
    good = tmp_path / "cal.json"
    good.write_text('{"verdict": "ok", "in use": true}\n')
    assert calibrate("vive-desk", data, "--no-samples", "--json", good) == 1
    assert good.read_text() == '{"verdict": "ok", "in use": true}\n'
    kept = json.loads((tmp_path / "cal.unusable.json").read_text())
    assert kept["verdict"] == "degenerate" and "kept" in capsys.readouterr().out
    before = data.read_bytes()
    assert calibrate("vive-desk", data, "--json", data) == 2  # never over the data file
    assert data.read_bytes() == before


# --------------------------------------------------------------------------- exit code 2


@pytest.fixture(scope="module")
def tcp_recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "tcp.mcap"
    summary, _ = run(RECIPES / "calibrate_tcp_sim.yaml", record=path)
    assert summary.ok
    return path


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def bad_inputs(tmp_path: Path, rec: Path) -> list[tuple[list[object], str]]:
    sim = _vive(points=SEED_POINTS_3[:2], orientations=1)
    save_vive_json(sim.data, tmp_path / "two_points.json")
    write_pose_pairs_json(
        tmp_path / "two.json", *[load_pose_pairs(MOVEIT).T_base_tcp[:2], load_pose_pairs(MOVEIT).T_cam_target[:2]]
    )
    header = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
    rows = "".join(f"{10 * k},{-20 + k},{30},{k},{5 * k},{-k},{400 + k},{100 - k},{300 + 2 * k}\n" for k in range(5))
    metres = "".join(f"{10 * k},{-20 + k},30,{k},{5 * k},{-k},0.4{k},0.1{k},0.3{k}\n" for k in range(12))
    garbage = _write(tmp_path, "garbage.mcap", "not an mcap file")
    return [
        (["handeye", tmp_path / "missing.json"], "no such file"),
        (["handeye", _write(tmp_path, "poses.txt", "1 2 3")], "unsupported file type '.txt'"),
        (["handeye", _write(tmp_path, "wrong.json", '{"format": "something/9"}')], "unknown JSON format"),
        (["handeye", _write(tmp_path, "cols.csv", "id,x,y\n1,2,3\n")], "missing columns"),
        (["handeye", tmp_path / "two.json"], "2 pose pair(s): hand-eye calibration needs at least 3"),
        (["handeye", MOVEIT, "--setup", "eye_to_hand", "--mm"], "millimetres"),
        (["vive-desk", tmp_path / "two_points.json"], "at least 3 distinct contact points"),
        (["vive-desk", _write(tmp_path, "v.json", '{"contacts": [{"label": "P1"}]}')], "missing field 'desk_point'"),
        (["tcp", _write(tmp_path, "t.json", '{"format": "vgr.tcp_camera/1", "samples": []}')], "no samples"),
        (["kinematics", _write(tmp_path, "k.csv", header + rows)], "5 samples: a 6-joint position calibration needs at least 10"),
        (["kinematics", _write(tmp_path, "k.json", "{}")], "one object per pose"),
        (["kinematics", _write(tmp_path, "k2.json", '[{"q1_deg": 1, "x_mm": 2}]')], "missing column 'y_mm'"),
        (["kinematics", _write(tmp_path, "k.yaml", "a: 1")], "unsupported file type '.yaml'"),
        (["kinematics", _write(tmp_path, "m.csv", header + metres)], "they look like metres"),
        (["tcp", rec, "--point-topic", "/nope"], "no topic '/nope' (topics with PoseStamped messages: "),
        (["tcp", rec, "--point-topic", "/poses/joint_state"], "carries JointState messages, not PoseStamped"),
        (["handeye", rec], "no topic '/target/pose'"),
        (["tcp", rec, "--point-topic", "/poses/point", "--robot-topic", "/robot/tcp_pose", "--pair", "order"], "pairing by order needs equal counts"),
        (["tcp", rec, "--robot-topic", "/robot/tcp_pose", "--max-skew-s", "0"], "have no camera points within 0"),
        (["tcp", garbage], "garbage.mcap"),
    ]  # fmt: skip


def test_bad_input_exits_two_with_a_clear_message(tmp_path, tcp_recording, capsys):
    for args, message in bad_inputs(tmp_path, tcp_recording):
        code = calibrate(*args)
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        assert err.startswith("bad input: ") and message in err, (args, err)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_nan_or_infinity_anywhere_in_a_file_is_bad_input(tmp_path, capsys, data):
    s = load_pose_pairs(MOVEIT)
    path = tmp_path / "tcp.json"
    save_tcp_json(TcpCameraData.from_arrays(s.T_base_tcp[:12], s.T_cam_target[:12, :3, 3]), path)
    doc = json.loads(path.read_text())
    k = data.draw(st.integers(0, 11))
    field = data.draw(st.sampled_from(["flange_position", "flange_quat_xyzw", "p_cam"]))
    i = data.draw(st.integers(0, len(doc["samples"][k][field]) - 1))
    doc["samples"][k][field][i] = data.draw(st.sampled_from([float("nan"), float("inf"), -float("inf")]))
    path.write_text(json.dumps(doc))
    assert calibrate("tcp", path) == 2
    assert "bad input" in capsys.readouterr().err


def test_samples_with_a_pose_missing_are_dropped_and_named(tmp_path, capsys):
    """A view where the target was not detected is stored as NaN (JSON) or empty cells (CSV): the
    sample is left out with a note naming it, not refused as bad input; a pose only partly NaN, or
    an infinity, still is."""
    pairs = json.loads(MOVEIT.read_text())
    n = len(pairs)
    pairs[4][1] = [[float("nan")] * 4 for _ in range(4)]  # no detection in view 4
    pairs[7][0] = [[float("nan")] * 4 for _ in range(3)] + [[0, 0, 0, 1]]  # a robot pose not read in view 7
    (tmp_path / "nan.json").write_text(json.dumps(pairs))
    capsys.readouterr()
    code = calibrate("handeye", tmp_path / "nan.json", "--setup", "eye_to_hand", "--json", tmp_path / "r.json")
    out = capsys.readouterr().out
    assert code in (0, 3), out
    assert "dropped 2 sample(s) with a pose missing: 4 (camera pose missing), 7 (robot pose missing)" in out
    res = json.loads((tmp_path / "r.json").read_text())
    assert within_one_percent(np.asarray(res["estimate"]["T_base_cam"])[:3, 3])
    samples = load_pose_pairs(tmp_path / "nan.json")
    assert len(samples.T_base_tcp) == n - 2 and "4" not in samples.ids and "7" not in samples.ids
    # CSV: empty cells for the camera pose of one row
    from scipy.spatial.transform import Rotation

    both = load_pose_pairs(MOVEIT)
    cols = [f"{side}_{c}" for side in ("base_tcp", "cam_target") for c in ("x", "y", "z", "rx", "ry", "rz")]
    rows = []
    for k, (M, B) in enumerate(zip(both.T_base_tcp, both.T_cam_target, strict=True)):
        vals = [
            *M[:3, 3],
            *Rotation.from_matrix(M[:3, :3]).as_rotvec(),
            *B[:3, 3],
            *Rotation.from_matrix(B[:3, :3]).as_rotvec(),
        ]
        rows.append(",".join("" if (k == 2 and i >= 6) else repr(float(v)) for i, v in enumerate(vals)))
    (tmp_path / "p.csv").write_text(",".join(cols) + "\n" + "\n".join(rows) + "\n")
    csv_samples = load_pose_pairs(tmp_path / "p.csv")
    assert len(csv_samples.T_base_tcp) == n - 1 and csv_samples.dropped == ["line 4 (camera pose missing)"]
    pairs[4][1] = [[float("inf")] * 4 for _ in range(4)]
    (tmp_path / "inf.json").write_text(json.dumps(pairs))
    assert calibrate("handeye", tmp_path / "inf.json", "--setup", "eye_to_hand") == 2
    pairs[4][1] = json.loads(MOVEIT.read_text())[4][1]
    pairs[4][1][1][3] = float("nan")  # one number of a pose: a damaged row, not a missing view
    (tmp_path / "part.json").write_text(json.dumps(pairs))
    assert calibrate("handeye", tmp_path / "part.json", "--setup", "eye_to_hand") == 2
