"""Lazy import of a device SDK, with an error that says which vgr extra installs it.

Hardware adapters (UR robot, Vive tracker, RealSense camera) import their vendor SDK only when a
stage of that type is set up, never at module import: ``import plugins...`` and ``vgr plugins`` work
on a machine without any SDK, and so does ``vgr replay`` of a recording made on the real cell
(replay feeds sensor and device stages from the file and never constructs them).
"""

from __future__ import annotations

import importlib
from types import ModuleType


class MissingSDKError(ImportError):
    """A stage needs a vendor SDK that is not installed; the message says how to install it."""


def import_sdk(module: str, *, stage_type: str, extra: str, package: str) -> ModuleType:
    """Import *module* (e.g. ``pyrealsense2``) for *stage_type*, or raise :class:`MissingSDKError`.

    *extra* is the vgr extra that installs the SDK (``pip install 'vgr[extra]'``) and *package* the
    PyPI distribution (``pip install package``), both named in the message.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingSDKError(
            f"stage type {stage_type!r} needs the Python module {module!r} (PyPI package {package!r}), "
            f"which cannot be imported: {exc}. Install it with: pip install 'vgr[{extra}]' "
            f"(or: pip install {package})"
        ) from exc
