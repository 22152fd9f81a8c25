"""What every build step shares: the install layout, progress logging and the build error."""

from __future__ import annotations

import sys
import sysconfig
from dataclasses import dataclass
from pathlib import Path

# The command-line script; the round trip's child processes are started through it.
ENTRY_POINT = Path(__file__).resolve().parents[1] / "build_tf2_msgs.py"


def log(message: str) -> None:
    """Print a progress line prefixed with the tool name."""
    print(f"[build_tf2_msgs] {message}", flush=True)


class BuildError(RuntimeError):
    """A build prerequisite is missing or a build step failed."""


@dataclass(frozen=True)
class Layout:
    """Where the package goes: the environment prefix and its site-packages."""

    prefix: Path
    site_packages: Path

    @property
    def lib(self) -> Path:
        return self.prefix / "lib"

    @property
    def include(self) -> Path:
        return self.prefix / "include"

    @property
    def share(self) -> Path:
        return self.prefix / "share"

    @classmethod
    def current(cls) -> Layout:
        return cls(prefix=Path(sys.prefix), site_packages=Path(sysconfig.get_paths()["platlib"]))
