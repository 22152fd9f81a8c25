"""TCP calibration with a camera (seed 002) on simulated data with camera noise and on real
MoveIt hand-eye data (marker origin as the observed TCP point)."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from shared_data import SHARED

from engine.transforms import T_from_Rt, inv, log_so3, pose_error
from plugins.calibration.pose_lsq.stats import Identifiability, analyse_identifiability
from plugins.calibration.tcp_camera import (
    TcpCameraData,
    TcpNoiseModel,
    calibrate_tcp_camera,
    load_tcp_csv,
    load_tcp_json,
    save_tcp_csv,
    save_tcp_json,
)
from plugins.calibration.tcp_camera.simulate import TRUE_P_FLANGE_TCP, simulate_tcp_camera, true_T_base_cam
from plugins.calibration.tcp_camera.solver import PARAM_NAMES, _null_space_issue, _Problem, cramer_rao_bound

MOVEIT = SHARED / "moveit_calibration" / "pose_samples.json"


def err9(res, sim):
    T = res.estimate["T_cam_base"]
    return np.concatenate(
        [
            T[:3, 3] - sim.T_cam_base[:3, 3],
            log_so3(T[:3, :3] @ sim.T_cam_base[:3, :3].T),
            res.estimate["p_flange_tcp"] - sim.p_flange_tcp,
        ]
    )


@pytest.mark.parametrize("kw", [{}, {"n_translations": 0, "n_rotations": 16}])
def test_noise_free_data_recovers_the_truth(kw):
    sim = simulate_tcp_camera(seed=1, camera_sigma_m=1e-12, **kw)
    res = calibrate_tcp_camera(sim.data)
    assert np.max(np.abs(err9(res, sim))) < 1e-8
    assert res.metrics["init_method_is_seed002"] == (1.0 if not kw else 0.0)
    # the closed form alone is exact on exact data, too
    assert pose_error(res.estimate["closed_form_T_cam_base"], sim.T_cam_base)[0] < 1e-8


def test_accuracy_with_camera_noise_and_residuals():
    """0.3 mm camera noise, 6 translations + 10 rotations (<= 30 deg): TCP within ~1 mm, camera
    rotation within 0.3 deg, residual RMS per axis at the noise level, truth in the ellipsoid."""
    sim = simulate_tcp_camera(seed=2)
    res = calibrate_tcp_camera(sim.data)
    assert res.usable, res.reasons
    e = err9(res, sim)
    assert np.linalg.norm(e[6:]) < 1.5e-3 and np.degrees(np.linalg.norm(e[3:6])) < 0.3
    assert e @ np.linalg.solve(res.covariance, e) < chi2.ppf(0.999, 9)
    per_axis_rms = np.sqrt(np.mean(res.residuals**2))
    assert 0.15e-3 < per_axis_rms < 0.4e-3
    assert res.residuals.shape == (16, 3) and not res.outliers.any()
    assert 0.4 < res.metrics["chi2_per_dof"] < 1.8


@pytest.mark.slow
def test_monte_carlo_ml_near_crlb_and_better_than_the_seed_closed_form():
    errs, seeds, inside = [], [], 0
    crlb = np.zeros((9, 9))  # random orientation changes per trial: compare with the mean bound
    for k in range(40):
        sim = simulate_tcp_camera(seed=100 + k)
        c, rank = cramer_rao_bound(sim.data, sim.T_cam_base, sim.p_flange_tcp)
        assert rank == 9
        crlb += c / 40
        res = calibrate_tcp_camera(sim.data)
        e = err9(res, sim)
        errs.append(e)
        inside += e @ np.linalg.solve(res.covariance, e) < chi2.ppf(0.95, 9)
        Tc = res.estimate["closed_form_T_cam_base"]
        seeds.append(np.linalg.norm(log_so3(Tc[:3, :3] @ sim.T_cam_base[:3, :3].T)))
    E = np.array(errs)
    for s in (slice(0, 3), slice(3, 6), slice(6, 9)):
        ratio = np.sqrt(np.mean(np.sum(E[:, s] ** 2, 1))) / np.sqrt(np.trace(crlb[s, s]))
        assert ratio < 1.15, (s, ratio)
    assert inside / 40 >= 0.85
    # seed 002 gets the rotation from the pure translations only; ML uses every sample
    assert np.sqrt(np.mean(np.sum(E[:, 3:6] ** 2, 1))) < np.sqrt(np.mean(np.square(seeds)))


def test_rotations_about_one_axis_are_degenerate_with_advice():
    sim = simulate_tcp_camera(seed=3, rotation_axis=[0, 0, 1])
    res = calibrate_tcp_camera(sim.data)
    assert res.verdict == "degenerate" and not res.usable
    assert res.metrics["design_rank"] == 8
    msg = next(r for r in res.reasons if "degenerate" in r)
    assert "TCP component along flange axis" in msg and "+1.00]" in msg  # the flange z axis, sign fixed
    assert any("second, different axis" in a for a in res.advice)
    # the components perpendicular to the axis are still right
    assert np.linalg.norm((res.estimate["p_flange_tcp"] - sim.p_flange_tcp)[:2]) < 2e-3


def test_collinear_tcp_positions_leave_the_camera_roll_unobservable():
    R0 = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    T = np.array([T_from_Rt(R0, [0.4 + 0.05 * k, 0.0, 0.3]) for k in range(6)])
    T_cam_base = inv(true_T_base_cam())
    p_cam = np.array([(T_cam_base @ Ti @ np.append(TRUE_P_FLANGE_TCP, 1))[:3] for Ti in T])
    res = calibrate_tcp_camera(TcpCameraData.from_arrays(T, p_cam, noise=TcpNoiseModel()), init="seed002")
    assert res.verdict == "degenerate"
    assert any("camera-to-base rotation about" in r for r in res.reasons)
    assert any("two non-parallel directions" in a for a in res.advice)
    assert any("the whole TCP point" in r for r in res.reasons)


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=20, deadline=None)
def test_degenerate_message_does_not_depend_on_which_null_space_basis_the_svd_returned(seed):
    """A 4-dimensional null space has no unique basis: another LAPACK build may return any
    rotation of it. The message must name the same unobservable directions for every basis."""
    R0 = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    T = np.array([T_from_Rt(R0, [0.4 + 0.05 * k, 0.0, 0.3]) for k in range(6)])
    p_cam = np.array([(inv(true_T_base_cam()) @ Ti @ np.append(TRUE_P_FLANGE_TCP, 1))[:3] for Ti in T])
    problem = _Problem(
        TcpCameraData.from_arrays(T, p_cam, noise=TcpNoiseModel()), inv(true_T_base_cam()), TRUE_P_FLANGE_TCP
    )
    J = problem.residual_and_jacobian(np.zeros(9))[1]
    ident = analyse_identifiability(J, PARAM_NAMES, np.full(9, 1e-3))
    assert ident.null_space.shape[0] == 4
    Q = np.linalg.qr(np.random.default_rng(seed).normal(size=(4, 4)))[0]  # any orthonormal mixing
    mixed = Identifiability(ident.rank, ident.n_params, ident.singular_values, Q @ ident.null_space)
    msg = _null_space_issue(mixed).message
    assert "the whole TCP point" in msg and "camera-to-base rotation about camera axis" in msg
    assert "[-0.09, +0.87, -0.49]" in msg or "[+0.09, -0.87, +0.49]" in msg


def test_displaced_sample_is_flagged_and_a_robust_loss_limits_its_damage():
    sim = simulate_tcp_camera(seed=5, n_rotations=14)
    p = sim.data.p_cam.copy()
    p[9] += [0.006, -0.004, 0.0]  # a wrong marker detection
    data = TcpCameraData.from_arrays(sim.data.T_base_flange, p, noise=sim.data.noise)
    res = calibrate_tcp_camera(data)
    assert res.outliers[9] and res.outliers.sum() == 1
    assert any("S10" in a for a in res.advice)
    robust = calibrate_tcp_camera(data, loss="soft_l1")
    e_lin = np.linalg.norm(res.estimate["p_flange_tcp"] - sim.p_flange_tcp)
    e_rob = np.linalg.norm(robust.estimate["p_flange_tcp"] - sim.p_flange_tcp)
    assert e_rob < e_lin


@pytest.mark.parametrize(
    ("case", "match"),
    [
        ("nan", "NaN"),
        ("few", "at least 4 samples"),
        ("dup", "identical"),
        ("robot_mm", "flange positions .* millimetres"),
        ("cam_mm", "camera points .* millimetres"),
        ("mixed", "mixed units"),
        ("shear", "not a rotation"),
    ],
)
def test_bad_input_is_rejected(case, match):
    sim = simulate_tcp_camera(seed=6)
    T, p = sim.data.T_base_flange.copy(), sim.data.p_cam.copy()
    if case == "nan":
        p[3, 1] = np.nan
    elif case == "few":
        T, p = T[:3], p[:3]
    elif case == "dup":
        T, p = np.vstack([T, T[:1]]), np.vstack([p, p[:1]])
    elif case == "robot_mm":
        T[:, :3, 3] *= 1000
    elif case == "cam_mm":
        p *= 1000
    elif case == "mixed":  # a scale error small enough to pass the magnitude check; pure
        p *= 5  # translations must move the TCP as far in the camera as the flange moved
    else:
        T[2, :3, :3] = T[2, :3, :3] @ np.diag([1.0, 1.02, 1.0])
    with pytest.raises(ValueError, match=match):
        calibrate_tcp_camera(TcpCameraData.from_arrays(T, p))


@pytest.mark.parametrize("fmt", ["json", "csv"])
def test_file_round_trip(tmp_path, fmt):
    sim = simulate_tcp_camera(seed=7)
    path = tmp_path / f"tcp.{fmt}"
    (save_tcp_json if fmt == "json" else save_tcp_csv)(sim.data, path)
    data = (load_tcp_json if fmt == "json" else load_tcp_csv)(path)
    assert data.noise == sim.data.noise and data.labels == sim.data.labels
    a, b = calibrate_tcp_camera(data), calibrate_tcp_camera(sim.data)
    assert np.allclose(a.estimate["p_flange_tcp"], b.estimate["p_flange_tcp"], atol=1e-10)


def test_ur_pose_csv_in_millimetres(tmp_path):
    sim = simulate_tcp_camera(seed=8)
    lines = ["# units = mm", "# camera_units = mm", "# camera_sigma = 0.3",
             "flange_x,flange_y,flange_z,flange_rx,flange_ry,flange_rz,cam_x,cam_y,cam_z"]  # fmt: skip
    for T, p in zip(sim.data.T_base_flange, sim.data.p_cam, strict=True):
        rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        lines.append(",".join(repr(float(v)) for v in (*(T[:3, 3] * 1000), *rv, *(p * 1000))))
    (tmp_path / "ur.csv").write_text("\n".join(lines))
    data = load_tcp_csv(tmp_path / "ur.csv")
    assert np.allclose(data.T_base_flange, sim.data.T_base_flange, atol=1e-12)
    assert np.allclose(data.noise.camera_sigma_m, 0.3e-3)
    with pytest.raises(ValueError, match="header needs"):
        (tmp_path / "bad.csv").write_text("flange_x,cam_x\n1,2\n")
        load_tcp_csv(tmp_path / "bad.csv")


def test_moveit_real_data_camera_pose_within_moveit_tolerance():
    """Real eye-to-hand samples (MoveIt): the marker origin seen by the camera is a TCP point.
    Position-only data recover MoveIt's asserted T_base_cam translation (0.659, -0.249, 0.830) m
    within its 1 % and its rotation within 1 deg; residual RMS 4.5 mm (3-D) is printed."""
    d = json.loads(MOVEIT.read_text())
    data = TcpCameraData.from_marker_poses(
        [s[0] for s in d], [s[1] for s in d], noise=TcpNoiseModel((2.6e-3, 2.6e-3, 2.6e-3))
    )
    res = calibrate_tcp_camera(data)
    t = res.estimate["T_base_cam"][:3, 3]
    ref = np.array([0.659, -0.249, 0.830])
    p_mm = np.round(res.estimate["p_flange_tcp"] * 1e3, 2)
    m = res.metrics
    print(f"t_base_cam = {np.round(t, 4)} m, p_flange_tcp = {p_mm} mm, residual RMS {m['rms_error_mm']:.2f} mm")
    assert np.all(np.abs(t - ref) <= 0.01 * np.abs(ref))
    R_ref = Rotation.from_euler("XYZ", [0.230, -2.540, 1.950]).as_matrix()  # Eigen eulerAngles(0,1,2)
    angle = np.degrees(Rotation.from_matrix(R_ref.T @ res.estimate["T_base_cam"][:3, :3]).magnitude())
    assert angle < 1.0
    assert res.usable and not res.outliers.any()
    assert 3.5 < res.metrics["rms_error_mm"] < 5.5
    assert 0.7 < res.metrics["chi2_per_dof"] < 1.5


@settings(max_examples=10, deadline=None)
@given(
    st.tuples(*[st.floats(-3.0, 3.0, allow_nan=False)] * 3),
    st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3),
)
def test_moving_the_camera_changes_only_T_cam_base(rv, t):
    """Equivariance: camera points re-expressed in another camera frame C' change T_cam_base to
    T_C'_C @ T_cam_base and leave the TCP point unchanged."""
    sim = simulate_tcp_camera(seed=9)
    T_new = T_from_Rt(Rotation.from_rotvec(rv).as_matrix(), t)
    p_new = sim.data.p_cam @ T_new[:3, :3].T + T_new[:3, 3]
    a = calibrate_tcp_camera(sim.data)
    b = calibrate_tcp_camera(TcpCameraData.from_arrays(sim.data.T_base_flange, p_new, noise=sim.data.noise))
    dt, dr = pose_error(T_new @ a.estimate["T_cam_base"], b.estimate["T_cam_base"])
    assert dt < 1e-7 and dr < 1e-7
    assert np.allclose(a.estimate["p_flange_tcp"], b.estimate["p_flange_tcp"], atol=1e-8)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 15), st.integers(0, 2), st.sampled_from(["cam", "pos", "rot"]))
def test_nan_anywhere_is_rejected(i, j, where):
    sim = simulate_tcp_camera(seed=10)
    T, p = sim.data.T_base_flange.copy(), sim.data.p_cam.copy()
    if where == "cam":
        p[i, j] = np.nan
    elif where == "pos":
        T[i, j, 3] = np.nan
    else:
        T[i, j, (j + 1) % 3] = np.inf
    with pytest.raises(ValueError, match="NaN"):
        TcpCameraData.from_arrays(T, p)
