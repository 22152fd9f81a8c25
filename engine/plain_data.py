"""Plain Python data from results that hold numpy values: what ``json`` and ``yaml`` writers take
(the model-gap report, calibration and registration results), and plain data read back from a file.

:func:`plain` turns arrays into (nested) lists, numpy scalars into Python numbers, tuples into
lists and mapping keys into strings, recursively; with ``nan_as_none`` non-finite floats become
``None`` (JSON has no NaN). :func:`read_document` reads a JSON or YAML file a user named (a robot
model file, samples, a stored result) with one error for a missing file and one for a broken one.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml


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


def read_document(path: str | Path, kind: Literal["json", "yaml"], what: str = "file") -> Any:
    """The plain data in the *kind* file *path*; ValueError naming it (as *what*, e.g. ``robot
    model file``) when it does not exist or is not valid JSON / YAML."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{what} {path} does not exist")
    text = path.read_text(encoding="utf-8")
    try:
        return json.loads(text) if kind == "json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as e:
        raise ValueError(f"{what} {path} is not valid {kind.upper()}: {e}") from None
