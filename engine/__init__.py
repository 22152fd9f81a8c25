"""vgr engine: recipes, DAG, plugin manager, zenoh bus, codecs, runner, recorder, replay and CLI.

Import packages are ``engine`` (this) and ``plugins`` (built-in stages); the distribution and the
command are ``vgr``.

BLAS runs single-threaded in vgr (``VGR_BLAS_THREADS`` overrides; an explicit
``OPENBLAS_NUM_THREADS`` / ``MKL_NUM_THREADS`` wins): its linear algebra is on small or thin
matrices, where a threaded OpenBLAS is slower, not faster (a 60k x 3 point transform took 24 ms with
2 threads against 2 ms with one, on the 2-core CI machine), and a thread count must never change a
result (docs/design.md, determinism). The variables are set before numpy loads when vgr is imported
first; otherwise the BLAS thread pool is limited at import through threadpoolctl.

OpenBLAS picks its kernels by CPU at load time, and kernels for different CPUs round differently:
a golden recording made on a machine with AVX-512 replayed "within tolerance" (1e-15 to 1e-12),
not identical, on the same machine with OpenBLAS told to use its AVX2 (Haswell) kernels. On x86-64
with AVX2 and FMA vgr therefore pins ``OPENBLAS_CORETYPE=Haswell`` (an explicit setting wins), so a
recording replays bit for bit on any such machine. This too only works when vgr is imported before
numpy (the ``vgr`` command, tests/conftest.py); :data:`BLAS_CORETYPE` says what was asked for.
"""

import os
import sys

__version__ = "0.1.0"

BLAS_THREADS = int(os.environ.get("VGR_BLAS_THREADS", "1"))


def _x86_avx2_fma() -> bool:
    """True on an x86-64 CPU with AVX2 and FMA (read from /proc/cpuinfo; False elsewhere)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return {"avx2", "fma"} <= flags
    except OSError:
        pass
    return False


if "OPENBLAS_CORETYPE" not in os.environ and "numpy" not in sys.modules and _x86_avx2_fma():
    os.environ["OPENBLAS_CORETYPE"] = "Haswell"
BLAS_CORETYPE = os.environ.get("OPENBLAS_CORETYPE")
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, str(BLAS_THREADS))
if "numpy" in sys.modules:  # numpy came first: the variables are too late for its BLAS, limit the pool
    from threadpoolctl import threadpool_limits

    threadpool_limits(BLAS_THREADS, user_api="blas")
