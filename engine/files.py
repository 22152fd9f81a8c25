"""Replacing files so that a failure never leaves half of one: :func:`replacing`, :func:`replace_text`.

Used wherever vgr writes over a file a user may depend on (golden recordings, recovered recordings,
recipes, calibration results): the new content goes to a temporary file beside the target and is
renamed over it only once complete (atomic on POSIX: a crash leaves the old file or the new one).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside *path* to write the new content to; when the block ends without
    an exception it is renamed over *path* (an existing file's mode is kept), and in every case no
    temporary file is left behind."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial")
    try:
        yield tmp
        if path.exists():
            shutil.copymode(path, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def replace_text(path: str | Path, text: str) -> Path:
    """Write *text* to *path* through :func:`replacing`; returns *path*."""
    with replacing(path) as tmp:
        tmp.write_text(text)
    return Path(path)
