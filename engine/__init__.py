"""vgr engine: recipes, DAG, plugin manager, zenoh bus, codecs, runner, recorder, replay and CLI.

Import packages are ``engine`` (this) and ``plugins`` (built-in stages); the distribution and the
command are ``vgr``.

BLAS runs single-threaded in vgr (``VGR_BLAS_THREADS`` overrides; an explicit
``OPENBLAS_NUM_THREADS`` / ``MKL_NUM_THREADS`` wins): its linear algebra is on small or thin
matrices, where a threaded OpenBLAS is slower, not faster (a 60k x 3 point transform took 24 ms with
2 threads against 2 ms with one, on the 2-core CI machine), and a thread count must never change a
result (DESIGN.md, determinism). The variables are set before numpy loads when vgr is imported
first; otherwise the BLAS thread pool is limited at import through threadpoolctl.
"""

import os
import sys

__version__ = "0.1.0"

BLAS_THREADS = int(os.environ.get("VGR_BLAS_THREADS", "1"))
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, str(BLAS_THREADS))
if "numpy" in sys.modules:  # numpy came first: the variables are too late for its BLAS, limit the pool
    from threadpoolctl import threadpool_limits

    threadpool_limits(BLAS_THREADS, user_api="blas")
