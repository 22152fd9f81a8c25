"""Writing files safely: :func:`replacing` / :func:`replace_text` never leave half of a file,
:func:`create_new` never writes through a link.

Used wherever vgr writes over a file a user may depend on (golden recordings, recovered recordings,
recipes, calibration results): the new content goes to a temporary file beside the target and is
renamed over it only once complete (atomic on POSIX: a crash leaves the old file or the new one).
The temporary file has an unpredictable name and is created exclusively (``tempfile.mkstemp``:
``O_EXCL``), so a link planted beside the target by another user is never written through; the
rename replaces a link at the target itself, not the file it points to. :func:`create_new` makes a
file that must not exist yet (``O_EXCL | O_NOFOLLOW``): a file or a link, dangling or not, put there
meanwhile makes it fail instead of being followed.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside *path* to write the new content to; when the block ends without
    an exception it is renamed over *path* (an existing file's mode is kept), and in every case no
    temporary file is left behind."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        if path.exists():
            shutil.copymode(path, tmp)
        else:
            tmp.chmod(0o644)  # (mkstemp made it 0600; a new file is readable as one made by open would be)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def create_new(path: str | Path, mode: int = 0o644) -> BinaryIO:
    """*path* created (with *mode*) and opened for writing; FileExistsError when anything (a file, a
    link) is there."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
    return os.fdopen(fd, "wb")


def replace_text(path: str | Path, text: str) -> Path:
    """Write *text* to *path* through :func:`replacing`; returns *path*."""
    with replacing(path) as tmp:
        tmp.write_text(text)
    return Path(path)
