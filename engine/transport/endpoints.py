"""Where a run's zenoh sessions listen and connect: private unix sockets (``listen: [private]``), one
per process of a run, in a folder only the user can enter, and finding the sockets of the runs that
are up. The grammar of endpoint strings is engine.recipe.endpoint_syntax.
"""

from __future__ import annotations

import glob
import os
import stat
import tempfile
from pathlib import Path


def private_socket_dir() -> Path:
    """A folder only this user can open, for the unix sockets of runs on this host:
    ``$XDG_RUNTIME_DIR/vgr`` when set (systemd makes that folder per user, mode 0700), else
    ``<tmp>/vgr-<uid>``. Created 0700; refused (PermissionError) when it exists but belongs to
    another user or others may open it, because a folder planted there by someone else would let
    them take the sockets' names."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    folder = Path(runtime) / "vgr" if runtime else Path(tempfile.gettempdir()) / f"vgr-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    st = folder.lstat()
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise PermissionError(
            f"{folder} must be a folder of user {os.getuid()} with mode 0700 (it is uid {st.st_uid}, "
            f"mode {stat.S_IMODE(st.st_mode):o}): remove it, or set XDG_RUNTIME_DIR to a private folder"
        )
    return folder


def private_socket(run: str, process: str) -> str:
    """The endpoint of *process* of run *run* in private_socket_dir() (the run's folder is made 0700)."""
    run_dir = private_socket_dir() / run
    run_dir.mkdir(mode=0o700, exist_ok=True)
    return f"unixsock-stream/{run_dir / f'{process}.sock'}"


def run_sockets(run: str | None = None) -> list[str]:
    """Endpoints of the sockets run *run*'s processes listen on (those that exist now; None: every
    run of this user on this host). A socket a killed run left behind connects to nothing."""
    runs = "*" if run is None else glob.escape(run)
    return sorted(f"unixsock-stream/{p}" for p in private_socket_dir().glob(f"{runs}/*.sock"))
