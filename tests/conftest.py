"""Test-suite set-up: helper modules living next to the tests of each area are importable.

pytest runs with ``--import-mode=importlib`` (test files in different folders may share a base
name), which does not put test folders on ``sys.path``; a folder's helper module (e.g.
``tests/sim/simcam_helpers.py``) is made importable here instead.

``engine`` is imported first, before anything loads numpy: it fixes the BLAS threads and kernels
that bit-identical replay relies on (engine/__init__.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import engine  # noqa: F401  (first: BLAS settings before numpy loads)

_TESTS = Path(__file__).resolve().parent
for _d in sorted(p for p in _TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "__"))):
    if str(_d) not in sys.path:
        sys.path.append(str(_d))

# Tests never assert wall-clock times, and hypothesis's per-example deadline is one: on a loaded
# 2-core CI machine an example that imports a module or starts a solver the first time can take
# longer than 200 ms and fail as "flaky" for no fault of the code.
from hypothesis import settings  # noqa: E402

settings.register_profile("vgr", deadline=None)
settings.load_profile("vgr")
