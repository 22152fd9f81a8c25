"""The correction formulas against an ideal simulated cell (exact algebra, random poses)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.transforms import T_from_rotvec, inv, pose_error
from plugins.actions import guidance_math as gm

seeds = st.integers(0, 2**31 - 1)


def rand_T(rng: np.random.Generator, t: float = 0.5, r: float = 0.5) -> np.ndarray:
    return T_from_rotvec(rng.normal(scale=r, size=3), rng.normal(scale=t, size=3))


def small_T(rng: np.random.Generator) -> np.ndarray:
    return T_from_rotvec(rng.uniform(-0.17, 0.17, 3), rng.uniform(-0.02, 0.02, 3))  # +-10 deg, +-20 mm


@settings(max_examples=200)
@given(seeds)
def test_eye_in_hand_one_step_converges_with_exact_hand_eye(seed):
    rng = np.random.default_rng(seed)
    T_tcp_cam, T0, P0 = rand_T(rng, 0.1), rand_T(rng), rand_T(rng)
    P = small_T(rng) @ P0  # the incoming part moved
    C0 = T0 @ T_tcp_cam
    T = T0
    T_match = inv(C0) @ P0 @ inv(P) @ (T @ T_tcp_cam)  # what a perfect matcher returns
    T_new = T @ gm.delta_eye_in_hand(T_match, T_tcp_cam)
    T_match_after = inv(C0) @ P0 @ inv(P) @ (T_new @ T_tcp_cam)
    assert np.allclose(T_match_after, np.eye(4), atol=1e-9)
    # the docking formula moves the install pose with the part
    T_install = rand_T(rng)
    want = P @ inv(P0) @ T_install
    assert np.allclose(gm.dock_eye_in_hand(T0, T_new, T_install), want, atol=1e-9)


@settings(max_examples=200)
@given(seeds)
def test_eye_to_hand_one_step_converges_with_exact_hand_eye(seed):
    rng = np.random.default_rng(seed)
    T_base_cam, T0, G0 = rand_T(rng), rand_T(rng), rand_T(rng, 0.1)
    G = G0 @ small_T(rng)  # the part sits differently in the gripper
    T = T0
    T_match = inv(T_base_cam) @ T0 @ G0 @ inv(G) @ inv(T) @ T_base_cam
    T_new = gm.delta_eye_to_hand(T_match, T_base_cam) @ T
    assert np.allclose(T_new @ G, T0 @ G0, atol=1e-9)  # the part is where the template saw it
    T_install = rand_T(rng)
    assert np.allclose(gm.dock_eye_to_hand(T0, T_new, T_install) @ G, T_install @ G0, atol=1e-9)


@settings(max_examples=100)
@given(seeds)
def test_wrong_hand_eye_still_converges_by_iterating_and_docks_exactly(seed):
    rng = np.random.default_rng(seed)
    T_tcp_cam_true = rand_T(rng, 0.1)
    err = T_from_rotvec(np.radians([0.5, -0.3, 0.2]), [0.001, -0.0005, 0.0008])  # 1 mm / 0.5 deg class
    T_tcp_cam_believed = T_tcp_cam_true @ err
    T0, P0 = rand_T(rng), rand_T(rng)
    P = small_T(rng) @ P0
    C0 = T0 @ T_tcp_cam_true
    T = T0
    for _ in range(20):
        T_match = inv(C0) @ P0 @ inv(P) @ (T @ T_tcp_cam_true)
        if gm.converged(T_match, 1e-7, 1e-8):
            break
        T = T @ gm.delta_eye_in_hand(T_match, T_tcp_cam_believed)
    assert gm.converged(T_match, 1e-7, 1e-8)
    T_install = rand_T(rng)
    t_err, r_err = pose_error(gm.dock_eye_in_hand(T0, T, T_install), P @ inv(P0) @ T_install)
    assert t_err < 1e-6 and r_err < 1e-6


@settings(max_examples=100)
@given(seeds)
def test_dual_docks_the_carried_part_on_the_moved_part_as_taught(seed):
    """The cell, not the formula: the incoming part moved (P0 -> P) and the grasp changed (G0 -> G,
    part pose in the tool frame). Stage 1 (eye-in-hand) ends where the flange camera sees the part as
    taught; stage 2 (eye-to-hand) ends where the fixed camera sees the carried part at its taught
    place. The docked carried part must then sit on the moved part exactly as taught."""
    rng = np.random.default_rng(seed)
    P0, G0, T_install, T_s1, T_s2 = (rand_T(rng) for _ in range(5))
    P, G = small_T(rng) @ P0, G0 @ small_T(rng)
    T_e1 = P @ inv(P0) @ T_s1  # flange camera: inv(T) @ P as taught
    T_e2 = T_s2 @ G0 @ inv(G)  # fixed camera: the carried part T @ G where T_s2 @ G0 was
    T_dock = gm.dock_dual(T_s1, T_e1, T_install, T_s2, T_e2)
    taught = inv(P0) @ T_install @ G0  # carried part in the incoming part's frame, as taught
    t_err, r_err = pose_error(inv(P) @ T_dock @ G, taught)
    assert t_err < 1e-9 and r_err < 1e-9


def test_sizes_and_thresholds():
    T = T_from_rotvec([0, 0, np.radians(0.005)], [0.00005, 0, 0])
    assert gm.converged(T, 1e-4, np.radians(0.01))
    assert not gm.converged(T, 1e-5, np.radians(0.01))
    t, r = gm.correction_between(np.eye(4), T)
    assert abs(t - 5e-5) < 1e-12 and abs(r - np.radians(0.005)) < 1e-12


def test_a_loop_stalled_at_its_tolerance_is_told_to_raise_it_not_to_recalibrate():
    from types import SimpleNamespace

    from plugins.actions.guidance_math import not_converged_hint

    tol = SimpleNamespace(translation_tol_mm=0.001, rotation_tol_deg=0.001)
    stalled = not_converged_hint([3.0, 0.002, 0.0021, 0.0019], [1.0, 0.002, 0.0018, 0.0022], tol)
    assert "below what one look resolves" in stalled and "hand-eye" not in stalled
    slow = not_converged_hint([3.0, 1.5, 0.8, 0.4], [1.0, 0.5, 0.25, 0.12], tol)  # shrinking, far off
    assert "hand-eye" in slow
