"""What makes the matchers reproducible: Open3D's global random seed and its process-wide thread limit.

Findings (Open3D 0.20 with oneTBB, small_gicp 1.0.1, KISS-ICP 1.3.0; measured by
``tests/registration/test_registration_determinism.py`` and ``benchmarks/registration.py``):

* ``registration_ransac_based_on_feature_matching`` and ``PointCloud.segment_plane`` draw from Open3D's
  global generator (``o3d.utility.random.seed``). Left multi-threaded, RANSAC's result depends on the
  number of TBB threads (same seed, 1 vs 2 threads: different poses for 3 of 3 seeds on the bunny),
  so vgr runs both with Open3D limited to ONE thread and reseeds before every call.
* Every matcher is bit-identical run after run, at any ``num_threads`` and whatever Open3D's
  process-wide thread limit is: Open3D normals/FPFH/voxel grid, small_gicp's k-d tree, normals and
  covariances and all nearest-neighbour queries are per-point computations (``num_threads``
  parallelises only those), and the ICP solvers iterate on ONE thread
  (``fine_backends.SOLVER_THREADS``). Left to ``num_threads=2``, small_gicp's and Open3D's ICP
  reductions summed in a scheduling-dependent order: last-bit differences, also from run to run,
  that moved the stopping iteration and the pose by up to 1e-6 (m / rad).
* small_gicp's multi-threaded voxel grid is documented as non-deterministic and is never used.

``o3d.utility.set_max_threads`` is process-wide: :func:`open3d_threads` changes it for the duration of
a call and restores the previous value. Stages that run Open3D concurrently in several Python threads
would race on it; vgr's runner executes a stage's solver calls sequentially.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import open3d as o3d

_lock = threading.RLock()


@contextmanager
def open3d_threads(num_threads: int) -> Iterator[None]:
    """Limit Open3D to *num_threads* (>= 1) inside the block, then restore the previous limit."""
    if num_threads < 1:
        raise ValueError(f"num_threads must be >= 1, got {num_threads}")
    with _lock:
        previous = o3d.utility.get_max_threads()
        o3d.utility.set_max_threads(int(num_threads))
        try:
            yield
        finally:
            o3d.utility.set_max_threads(previous)


@contextmanager
def open3d_seeded(seed: int) -> Iterator[None]:
    """Single-threaded Open3D with its global generator reseeded: for RANSAC-type calls."""
    with open3d_threads(1):
        o3d.utility.random.seed(int(seed) & 0x7FFFFFFF)
        yield
