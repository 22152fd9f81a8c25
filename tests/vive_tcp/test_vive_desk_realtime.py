"""Real-time conversion T_desktop_tcp = inv(T_base_desktop) T_base_tracker T_tracker_tcp: the seed's
representations (via scipy) and the propagated uncertainty."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_rotvec, T_from_Rt, exp_so3, inv, log_so3
from plugins.calibration.vive_desk import DesktopTcpConverter, ViveNoiseModel, desktop_tcp
from plugins.calibration.vive_desk.realtime import desktop_tcp_jacobians
from plugins.calibration.vive_desk.simulate import true_T_base_desktop, true_T_tracker_tcp

small = st.floats(-2.5, 2.5, allow_nan=False)


def perturb(T, xi):
    """Decoupled perturbation: t + v, exp(w) R."""
    return T_from_Rt(exp_so3(xi[3:]) @ T[:3, :3], T[:3, 3] + xi[:3])


@settings(max_examples=30, deadline=None)
@given(st.tuples(small, small, small), st.tuples(small, small, small))
def test_conversion_and_representations(rv, t):
    T_BD, T_KC = true_T_base_desktop(), true_T_tracker_tcp()
    T_BK = T_from_rotvec(np.array(rv), np.array(t))
    out = DesktopTcpConverter(T_BD, T_KC).convert(T_BK)
    T = inv(T_BD) @ T_BK @ T_KC
    assert np.allclose(out.T_desktop_tcp, T, atol=1e-12)
    assert np.allclose(out.T_desktop_tcp, desktop_tcp(T_BK, T_BD, T_KC))
    R = T[:3, :3]
    assert np.allclose(Rotation.from_quat(out.quat_xyzw).as_matrix(), R, atol=1e-12) and out.quat_xyzw[3] >= 0
    roll, pitch, yaw = out.euler_zyx  # R = Rz(yaw) Ry(pitch) Rx(roll), the seed's convention
    Rz, Ry, Rx = (Rotation.from_euler(a, v).as_matrix() for a, v in (("z", yaw), ("y", pitch), ("x", roll)))
    assert np.allclose(Rz @ Ry @ Rx, R, atol=1e-9)
    assert np.allclose(exp_so3(out.rotvec), R, atol=1e-12)
    assert out.covariance is None
    d = out.to_dict(human=True)
    assert np.allclose(d["position_mm"], T[:3, 3] * 1e3)
    assert np.allclose(d["euler_zyx_roll_pitch_yaw_deg"], np.degrees([roll, pitch, yaw]))


def test_seed_euler_formula_agrees_away_from_gimbal_lock():
    """Seed 001's hand-written rotation_matrix_to_euler_zyx (roll=atan2(R21,R22), ...) matches."""
    R = Rotation.from_euler("ZYX", [0.7, -0.4, 1.1]).as_matrix()
    out = DesktopTcpConverter(np.eye(4), np.eye(4)).convert(T_from_Rt(R, [0, 0, 0]))
    sy = np.hypot(R[0, 0], R[1, 0])
    seed = (np.arctan2(R[2, 1], R[2, 2]), np.arctan2(-R[2, 0], sy), np.arctan2(R[1, 0], R[0, 0]))
    assert np.allclose(out.euler_zyx, seed)
    assert np.allclose(out.euler_zyx, (1.1, -0.4, 0.7))


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    T_BD, T_KC = true_T_base_desktop(), true_T_tracker_tcp()
    T_BK = T_from_rotvec(rng.normal(size=3), rng.normal(size=3))
    Jc, Jt = desktop_tcp_jacobians(T_BK, T_BD, T_KC)
    base = desktop_tcp(T_BK, T_BD, T_KC)

    def diff(T):
        return np.concatenate([T[:3, 3] - base[:3, 3], log_so3(T[:3, :3] @ base[:3, :3].T)])

    h = 1e-7
    for k in range(12):
        xi = np.zeros(6)
        xi[k % 6] = h
        A = perturb(T_BD, xi) if k < 6 else T_BD
        B = perturb(T_KC, xi) if k >= 6 else T_KC
        assert np.allclose(diff(desktop_tcp(T_BK, A, B)) / h, Jc[:, k], atol=1e-5)
    for k in range(6):  # tracker: position in base, rotation right-multiplied (tracker frame)
        T = T_BK.copy()
        if k < 3:
            T[k, 3] += h
        else:
            T[:3, :3] = T[:3, :3] @ exp_so3(np.eye(3)[k - 3] * h)
        assert np.allclose(diff(desktop_tcp(T, T_BD, T_KC)) / h, Jt[:, k], atol=1e-5)


def test_propagated_covariance_matches_sampling():
    """Calibration covariance + tracker jitter propagated to first order vs 4000 samples."""
    rng = np.random.default_rng(4)
    T_BD, T_KC = true_T_base_desktop(), true_T_tracker_tcp()
    A = rng.normal(size=(12, 12)) * 1e-3
    C = A @ A.T + np.diag([1e-6] * 3 + [1e-6] * 3 + [1e-6] * 3 + [1e-6] * 3)
    noise = ViveNoiseModel(tracker_position_sigma_m=0.5e-3, tracker_rotation_sigma_rad=np.radians(0.1))
    conv = DesktopTcpConverter(T_BD, T_KC, calibration_covariance=C, tracker_noise=noise)
    T_BK = T_from_rotvec([0.3, -1.2, 0.4], [0.5, 1.0, -1.9])
    out = conv.convert(T_BK)
    L = np.linalg.cholesky(C)
    samples = []
    for _ in range(4000):
        xi = L @ rng.normal(size=12)
        T = T_BK.copy()
        T[:3, 3] += rng.normal(scale=0.5e-3, size=3)
        T[:3, :3] = T[:3, :3] @ exp_so3(rng.normal(scale=np.radians(0.1), size=3))
        D = desktop_tcp(T, perturb(T_BD, xi[:6]), perturb(T_KC, xi[6:]))
        samples.append(
            np.concatenate([D[:3, 3] - out.T_desktop_tcp[:3, 3], log_so3(D[:3, :3] @ out.T_desktop_tcp[:3, :3].T)])
        )
    emp = np.cov(np.array(samples).T)
    assert np.allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(out.covariance)), rtol=0.08)


def test_converter_validates_inputs():
    with pytest.raises(ValueError, match="not a rotation"):
        DesktopTcpConverter(np.diag([1.0, 1.0, 2.0, 1.0]), np.eye(4))
    conv = DesktopTcpConverter(np.eye(4), np.eye(4))
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        conv.convert(bad)
    with pytest.raises(ValueError, match="12x12"):
        DesktopTcpConverter(np.eye(4), np.eye(4), calibration_covariance=np.eye(6))
