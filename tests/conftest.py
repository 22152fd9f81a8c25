"""Test-suite set-up: helper modules living next to the tests of each area are importable.

pytest runs with ``--import-mode=importlib`` (test files in different folders may share a base
name), which does not put test folders on ``sys.path``; a folder's helper module (e.g.
``tests/sim/simcam_helpers.py``) is made importable here instead.

The tests' own plugin files (``stage_fixtures.py``, ``calib_test_stages.py``, ...) are named in
their recipes by file name (``plugins: [stage_fixtures]``): ``VGR_PLUGIN_PATH`` lists the test
folders, for this process and the ``vgr`` processes the tests start (engine.recipe.plugin_entries).

``engine`` is imported first, before anything loads numpy: it fixes the BLAS threads and kernels
that bit-identical replay relies on (engine/__init__.py).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import engine  # noqa: F401  (first: BLAS settings before numpy loads)

_TESTS = Path(__file__).resolve().parent
for _d in sorted(p for p in _TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "__"))):
    if str(_d) not in sys.path:
        sys.path.append(str(_d))
os.environ["VGR_PLUGIN_PATH"] = os.pathsep.join(
    [str(_TESTS), *(str(p) for p in sorted(_TESTS.iterdir()) if p.is_dir() and not p.name.startswith((".", "__")))]
)

# Tests never assert wall-clock times, and hypothesis's per-example deadline is one: on a loaded
# 2-core CI machine an example that imports a module or starts a solver the first time can take
# longer than 200 ms and fail as "flaky" for no fault of the code.
from hypothesis import settings  # noqa: E402

settings.register_profile("vgr", deadline=None)
settings.load_profile("vgr")
