"""What makes the matchers reproducible: Open3D's global random seed and its process-wide thread limit.

Findings (Open3D 0.20 with oneTBB, small_gicp 1.0, KISS-ICP 1.3; measured by
``tests/registration/test_determinism.py`` and described in docs/registration.md):

* ``registration_ransac_based_on_feature_matching`` and ``PointCloud.segment_plane`` draw from Open3D's
  global generator (``o3d.utility.random.seed``). Their result depends on the number of TBB threads
  (each worker consumes its own share of the random stream), so vgr runs them with Open3D limited to
  ONE thread and reseeds before every call. With that, the same seed gives bit-identical output
  whatever thread count the caller allows elsewhere.
* Open3D ICP, normal estimation, voxel downsampling, small_gicp registration/normal estimation and
  KISS-ICP registration showed no thread-count dependence in our measurements for the thread counts
  we allow (1 and 2); small_gicp's multi-threaded voxel grid is documented as non-deterministic and
  is never used.

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
