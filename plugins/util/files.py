"""Writing user files so that a failure never leaves half of one: :func:`replace_text`."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def replace_text(path: str | Path, text: str) -> Path:
    """Write *text* to *path* atomically: into a temporary file beside it, then renamed over it (on
    POSIX a crash leaves the old file or the new one, never a mix). An existing file keeps its mode."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial")
    try:
        tmp.write_text(text)
        if path.exists():
            shutil.copymode(path, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
