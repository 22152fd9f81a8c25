"""Plain Python data from results that hold numpy values: what ``json`` and ``yaml`` writers take
(the model-gap report, calibration and registration results).

:func:`plain` turns arrays into (nested) lists, numpy scalars into Python numbers, tuples into
lists and mapping keys into strings, recursively; with ``nan_as_none`` non-finite floats become
``None`` (JSON has no NaN).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def plain(x: Any, *, nan_as_none: bool = False) -> Any:
    """*x* as plain Python data (see the module docstring); other values are returned as they are."""
    if isinstance(x, dict):
        return {str(k): plain(v, nan_as_none=nan_as_none) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v, nan_as_none=nan_as_none) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist(), nan_as_none=nan_as_none)
    if isinstance(x, np.generic):
        return plain(x.item(), nan_as_none=nan_as_none)
    if nan_as_none and isinstance(x, float) and not np.isfinite(x):
        return None
    return x
