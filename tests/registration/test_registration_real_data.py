"""Real scans from other projects (/work/shared/data, see its README): the Stanford bunny views bun0 and
bun4 from PCL's tests, and the LiDAR pair of small_gicp's tests.

Ground truth of the bunny pair
------------------------------
PCL's ``T_bun4_bun0`` (its PPF test, checked there to 0.1 per matrix element) maps bun0 points into
bun4's frame (``p_bun4 = T @ p_bun0``: median nearest-neighbour distance 21.6 mm -> 3.5 mm, its
inverse gives 38 mm). It is a hand-rounded value, not a registration result: a rotation of
0.600000 rad (cos = 0.825336, sin = 0.564642) about exactly the y axis, with t_y exactly 0. (It is
not the turntable's nominal 45 deg step of "bun045" either.) The Stanford 3D Scanning Repository's
own alignment of the same scans (bun.conf: bun045 at t = (-0.0520211, -0.000383981, -0.0109223),
q = (0.00548449, -0.294635, -0.0038555, 0.955586), applied as ``T_bun4_bun0 = inv([R(q)^T, t])``,
the only one of the 8 quaternion-order/direction conventions that fits) is a rotation of 0.5983 rad
about (0.019, -0.9997, -0.013) and lies 1.39 mm / 0.78 deg from PCL's value at the bun0 centroid.
The scans themselves decide between the two: bun0 mapped into bun4, point-to-plane RMS (bun4
normals, pairs within 10 mm) PCL 1.77 mm, Stanford 1.36 mm, vgr 1.35 mm; median nearest-neighbour
distance 3.49 / 3.23 / 3.20 mm. So vgr is held to the issue's 1 mm / 0.5 deg against Stanford's
alignment; against PCL's value it must be as far as Stanford's alignment is, within that same
1 mm / 0.5 deg (measured: vgr - PCL 1.55 mm / 1.01 deg, Stanford - PCL 1.39 mm / 0.78 deg), and fit
the scans better than PCL's value does. Errors are measured at the bun0 centroid (translation) and
as the rotation angle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from shared_data import SHARED

from engine import transforms as tf
from plugins.registration import (
    BACKENDS,
    FineParams,
    FpfhParams,
    GlobalParams,
    PreprocessParams,
    register_fine,
    register_global,
)

DATA = SHARED

T_BUN4_BUN0_PCL = np.array(
    [[0.825336, 0, -0.564642, 0.037267], [0, 1, 0, 0], [0.564642, 0, 0.825336, 0.038325], [0, 0, 0, 1]]
)
_Q = (0.00548449, -0.294635, -0.0038555, 0.955586)
_T = (-0.0520211, -0.000383981, -0.0109223)
T_BUN4_BUN0_STANFORD = tf.inv(tf.T_from_Rt(Rotation.from_quat(_Q).as_matrix().T, _T))


def _read(path: Path) -> np.ndarray:
    if not path.is_file():
        pytest.fail(f"test data missing: {path} (set VGR_SHARED_DATA)")
    return np.asarray(o3d.io.read_point_cloud(str(path)).points)


@pytest.fixture(scope="module")
def bunny() -> tuple[np.ndarray, np.ndarray]:
    return _read(DATA / "pcl" / "bun0.pcd"), _read(DATA / "pcl" / "bun4.pcd")


def _err(T: np.ndarray, T_ref: np.ndarray, at: np.ndarray) -> tuple[float, float]:
    dt = np.linalg.norm(tf.transform_points(T, at[None]) - tf.transform_points(T_ref, at[None]))
    return float(dt * 1e3), float(np.degrees(tf.angle_between(T[:3, :3], T_ref[:3, :3])))


def _fit_rms(T: np.ndarray, bun0: np.ndarray, bun4: np.ndarray) -> float:
    """Point-to-plane RMS (m) of bun0 mapped by T into bun4 (bun4's 10-neighbour normals), pairs < 10 mm."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(bun4))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
    q = tf.transform_points(T, bun0)
    d, i = cKDTree(bun4).query(q)
    r = np.einsum("ij,ij->i", np.asarray(pcd.normals)[i], q - bun4[i])[d < 0.01]
    return float(np.sqrt(np.mean(r**2)))


def test_pcl_ground_truth_is_a_rounded_value_that_fits_the_scans_worse(bunny):
    bun0, bun4 = bunny
    tree = cKDTree(bun4)
    fwd = np.median(tree.query(tf.transform_points(T_BUN4_BUN0_PCL, bun0))[0])
    back = np.median(tree.query(tf.transform_points(tf.inv(T_BUN4_BUN0_PCL), bun0))[0])
    stanford = np.median(tree.query(tf.transform_points(T_BUN4_BUN0_STANFORD, bun0))[0])
    assert fwd < 0.004 < 0.03 < back  # the direction: p_bun4 = T @ p_bun0
    # PCL's value: 0.6 rad about exactly y, t_y = 0 (6-digit rounding of cos/sin 0.6)
    rotvec = Rotation.from_matrix(T_BUN4_BUN0_PCL[:3, :3]).as_rotvec()
    assert np.linalg.norm(rotvec) == pytest.approx(0.6, abs=1e-6)
    assert np.allclose(rotvec / np.linalg.norm(rotvec), [0.0, -1.0, 0.0], atol=1e-9)
    assert T_BUN4_BUN0_PCL[1, 3] == 0.0
    # Stanford's alignment fits the scans better, on both measures
    assert stanford < fwd
    assert _fit_rms(T_BUN4_BUN0_STANFORD, bun0, bun4) < _fit_rms(T_BUN4_BUN0_PCL, bun0, bun4) - 0.3e-3
    assert _err(T_BUN4_BUN0_PCL, T_BUN4_BUN0_STANFORD, bun0.mean(axis=0)) == pytest.approx((1.39, 0.78), abs=0.01)


BUNNY_PARAMS = GlobalParams(
    method="fpfh",
    # sparse scans (6 mm spacing): no downsampling, small_gicp's own 10-neighbour covariances
    # (the calibrated 1-sigma reads ~0.5 mm / 0.6 deg on them, the error against Stanford's
    # alignment is 0.21 mm / 0.43 deg: limits of 1 mm / 1 deg instead of the workpiece defaults)
    fine=FineParams(
        preprocess=PreprocessParams(voxel_size_m=0.0, normal_k=10, viewpoint=None),
        max_correspondence_m=0.02,
        max_sigma_translation_m=1e-3,
        max_sigma_rotation_rad=np.radians(1.0),
    ),
    coarse_voxel_m=0.0,
    fpfh=FpfhParams(runs=5),
    seed=0,
)


def test_bunny_recovered_from_20_arbitrary_poses(bunny):
    """bun0, moved by 20 random rigid motions (any rotation, +-20 cm), registered onto bun4 with no
    initial guess: every run lands on the same pose, within the issue's 1 mm / 0.5 deg of Stanford's
    alignment; PCL's rounded value is as far from it as Stanford's alignment is (module docstring),
    and the estimate fits the scans at least as well as Stanford's and better than PCL's."""
    bun0, bun4 = bunny
    rng = np.random.default_rng(2024)
    c0 = bun0.mean(axis=0)
    errs_stanford, errs_pcl, estimates = [], [], []
    for _ in range(20):
        T_move = tf.T_from_Rt(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.2, 0.2, 3))
        res = register_global(tf.transform_points(T_move, bun0), bun4, BUNNY_PARAMS)
        assert res.verdict == "ok", res.summary()
        T_bun4_bun0 = res.T_match @ T_move  # undo the arbitrary motion
        estimates.append(T_bun4_bun0)
        errs_stanford.append(_err(T_bun4_bun0, T_BUN4_BUN0_STANFORD, c0))
        errs_pcl.append(_err(T_bun4_bun0, T_BUN4_BUN0_PCL, c0))
    errs_stanford, errs_pcl = np.array(errs_stanford), np.array(errs_pcl)
    assert errs_stanford[:, 0].max() < 1.0 and errs_stanford[:, 1].max() < 0.5, errs_stanford.max(axis=0)
    stanford_to_pcl = np.array(_err(T_BUN4_BUN0_STANFORD, T_BUN4_BUN0_PCL, c0))  # 1.39 mm, 0.78 deg
    assert np.all(errs_pcl.max(axis=0) < stanford_to_pcl + np.array([1.0, 0.5])), errs_pcl.max(axis=0)
    spread = np.array([_err(T, estimates[0], c0) for T in estimates])
    assert spread.max(axis=0)[0] < 0.05 and spread.max(axis=0)[1] < 0.05  # one optimum, whatever the start
    fit = _fit_rms(estimates[0], bun0, bun4)
    assert fit <= _fit_rms(T_BUN4_BUN0_STANFORD, bun0, bun4) + 0.02e-3
    assert fit < _fit_rms(T_BUN4_BUN0_PCL, bun0, bun4) - 0.3e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_small_gicp_pair_matches_its_reference(backend):
    """small_gicp's LiDAR pair from the identity, every backend, LiDAR-sized parameters."""
    source = _read(DATA / "small_gicp" / "source.ply")
    target = _read(DATA / "small_gicp" / "target.ply")
    T_ref = np.loadtxt(DATA / "small_gicp" / "T_target_source.txt")
    params = FineParams(
        backend=backend,
        preprocess=PreprocessParams(voxel_size_m=0.25, normal_k=10),
        max_correspondence_m=1.0,
        kiss_voxel_m=2.0,  # KISS-ICP searches +-1 voxel: a voxel twice the correspondence distance
        max_sigma_translation_m=0.05,
        max_sigma_rotation_rad=np.radians(0.5),
    )
    res = register_fine(source, target, None, params)  # current = source, template = target
    assert res.verdict == "ok", res.summary()
    dt = np.linalg.norm(res.T_match[:3, 3] - T_ref[:3, 3])
    angle = np.degrees(tf.angle_between(res.T_match[:3, :3], T_ref[:3, :3]))
    assert dt < 0.02 and angle < 0.5, (dt, angle)
