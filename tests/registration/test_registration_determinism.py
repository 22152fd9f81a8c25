"""A fixed seed gives one answer, bit for bit, whatever the thread count (``num_threads`` 1, 2 or 4)
and whatever Open3D's process-wide thread limit is, run after run.

What makes it so (see determinism.py, fine_backends.py): threads only parallelise per-point work
(k-d trees, normals, covariances, FPFH, nearest-neighbour queries); the ICP solvers' reductions run
on one thread (summed on two they changed the last bits, then the stopping iteration, and the pose
by up to 1e-6); Open3D RANSAC and plane segmentation run seeded on one thread."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import registration_scenes as scenes

from engine import transforms as tf
from plugins.registration import (
    BACKENDS,
    FineParams,
    FpfhParams,
    GlobalParams,
    register_fine,
    register_global,
)


@pytest.fixture(scope="module")
def pair():
    cam = scenes.camera(640, 480)
    rng = np.random.default_rng(0)
    tmpl, cur = scenes.capture_pair("feature_part", cam, rng, max_shift_m=0.02, max_tilt_deg=10, spin_deg=None)
    T0 = scenes.true_match(tmpl, cur) @ tf.T_from_rotvec([0.01, 0.01, 0.02], [0.001, 0.0, 0.0])
    return tmpl.points, cur.points, T0


@pytest.fixture
def open3d_limit():
    """Set Open3D's process-wide thread limit for a test and restore the automatic default."""
    yield o3d.utility.set_max_threads
    o3d.utility.set_max_threads(0)


def _runs(fn, open3d_limit):
    out = []
    for limit in (1, 2, 1, 2):
        open3d_limit(limit)
        out.append(fn())
    return out


@pytest.mark.parametrize("backend", BACKENDS)
def test_fine_is_bit_identical_single_threaded(pair, backend, open3d_limit):
    tmpl, cur, T0 = pair
    runs = _runs(lambda: register_fine(cur, tmpl, T0, FineParams(backend=backend)).T_match, open3d_limit)
    assert runs[0] is not None, backend  # (np.array_equal(None, None) is True: compare real poses)
    assert all(np.array_equal(runs[0], T) for T in runs)


@pytest.mark.parametrize("method", ["fpfh", "planar", "auto"])
def test_global_is_bit_identical_for_a_seed(pair, method, open3d_limit):
    tmpl, cur, _ = pair
    params = GlobalParams(method=method, fpfh=FpfhParams(runs=2), seed=3)

    def run():
        res = register_global(cur, tmpl, params)
        return res.T_match if res.T_match is not None else res.details["T_candidate"]

    runs = _runs(run, open3d_limit)
    assert runs[0] is not None
    assert all(np.array_equal(runs[0], T) for T in runs)


@pytest.mark.parametrize("backend", BACKENDS)
def test_fine_is_bit_identical_at_any_thread_count(pair, backend):
    tmpl, cur, T0 = pair
    runs = [register_fine(cur, tmpl, T0, FineParams(backend=backend, num_threads=n)) for n in (1, 2, 4, 2)]
    assert runs[0].T_match is not None and runs[0].covariance is not None, backend
    assert all(np.array_equal(runs[0].T_match, r.T_match) for r in runs), backend
    assert all(np.array_equal(runs[0].covariance, r.covariance) for r in runs), backend


@pytest.mark.parametrize("method", ["planar", "auto"])
def test_global_is_bit_identical_at_two_threads(pair, method):
    tmpl, cur, _ = pair

    def run(threads: int) -> np.ndarray:
        params = GlobalParams(method=method, fine=FineParams(num_threads=threads), fpfh=FpfhParams(runs=2), seed=3)
        res = register_global(cur, tmpl, params)
        return res.T_match if res.T_match is not None else res.details["T_candidate"]

    a, b, c = run(1), run(2), run(2)
    assert a is not None and np.array_equal(a, b) and np.array_equal(b, c)


def test_different_seeds_may_differ_but_each_is_reproducible(pair):
    tmpl, cur, _ = pair

    def pose(res):  # the match, or the best candidate of a refused one
        return res.T_match if res.T_match is not None else res.details["T_candidate"]

    for seed in (0, 1):
        p = GlobalParams(method="fpfh", seed=seed)
        first = pose(register_global(cur, tmpl, p))
        assert first is not None and np.array_equal(first, pose(register_global(cur, tmpl, p)))


def test_global_with_the_edge_stage_is_bit_identical_at_two_threads():
    """The planar plate seen from above takes the contour edge stage (edges.py): same bits too."""
    cam = scenes.camera(640, 480)
    rng = np.random.default_rng(12)
    tmpl, cur = scenes.capture_pair("planar_plate", cam, rng, max_shift_m=0.02, max_tilt_deg=0, spin_deg=None)
    out = []
    for threads in (1, 2):
        res = register_global(cur.points, tmpl.points, GlobalParams(fine=FineParams(num_threads=threads), seed=1))
        assert res.verdict == "ok" and res.method.endswith("+edges"), res.summary()
        out.append(res)
    assert np.array_equal(out[0].T_match, out[1].T_match)
    assert np.array_equal(out[0].covariance, out[1].covariance)
