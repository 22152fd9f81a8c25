"""The BLAS settings that bit-identical replay relies on (engine/__init__.py) are in force: one
thread, and on x86-64 with AVX2 + FMA the Haswell kernels, whatever CPU the run is on."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy  # noqa: F401  (loads its OpenBLAS)
from threadpoolctl import threadpool_info

import engine


def _openblas() -> list[dict]:
    return [i for i in threadpool_info() if i.get("internal_api") == "openblas"]


def test_blas_runs_single_threaded_with_pinned_kernels_in_the_test_session() -> None:
    libs = _openblas()
    assert libs, "numpy's OpenBLAS not found"
    assert all(i["num_threads"] == engine.BLAS_THREADS == 1 for i in libs)
    if engine._x86_avx2_fma():
        assert engine.BLAS_CORETYPE == "Haswell"
        assert all(i["architecture"] == "Haswell" for i in libs), [i["architecture"] for i in libs]


def test_the_vgr_command_pins_the_kernels_and_an_explicit_setting_wins() -> None:
    code = (
        "import engine, numpy, scipy.linalg; from threadpoolctl import threadpool_info; "
        "print(sorted({i['architecture'] for i in threadpool_info() if i.get('internal_api') == 'openblas'}))"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    if engine._x86_avx2_fma():
        assert out.strip() == "['Haswell']"
    forced = subprocess.run(
        [sys.executable, "-c", code], env={**env, "OPENBLAS_CORETYPE": "Sandybridge"}, capture_output=True, text=True
    )
    if engine._x86_avx2_fma():
        assert forced.stdout.strip() == "['Sandybridge']", forced.stderr
