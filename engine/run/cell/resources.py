"""What a long-running service uses of the machine, for its ``status``: resident memory and open files
(Linux ``/proc``; None where it cannot be read)."""

from __future__ import annotations

import os


def rss_mb() -> float | None:
    """Resident set size of this process in MB."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            pages = int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def open_files() -> int | None:
    """File descriptors this process holds open."""
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:
        return None
