"""Where the real test data from other projects lives (../shared/data next to the checkout).

First of: ``$VGR_SHARED_DATA``, ``<checkout>/../shared/data``, ``/work/shared/data``. Tests that use
it fail (not skip) when a file is missing: a real-data test that silently skips proves nothing.
"""

from __future__ import annotations

import os
from pathlib import Path

_CANDIDATES = [
    *([Path(os.environ["VGR_SHARED_DATA"])] if os.environ.get("VGR_SHARED_DATA") else []),
    Path(__file__).resolve().parents[2] / "shared" / "data",
    Path("/work/shared/data"),
]
SHARED = next((p for p in _CANDIDATES if p.is_dir()), _CANDIDATES[-1])
