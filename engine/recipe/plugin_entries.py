"""What a recipe's ``plugins:`` entry (and ``vgr plugins --plugin``, ``vgr gap --plugin``, the model-gap
stage's ``effect_plugins``) may name, checked before anything is imported.

An entry is one of

* the name of an installed vgr plugin: an entry point of group ``vgr`` (``pip install`` registers
  it; vgr's own is ``builtin``);
* a path to a Python file (it contains ``/`` or ends in ``.py``), absolute or relative to the
  recipe's folder;
* the name of a file ``<name>.py`` in the recipe's folder or in a folder of ``VGR_PLUGIN_PATH``
  (folders separated by ``:``, as ``PATH``), the plugin folders the user names.

A file is loaded as a module named after it. Anything else is refused: a bare name used to import
whatever module of that name Python could find, so ``plugins: [this]`` ran an installed module's
import-time code. A plugin file runs with the rights of whoever runs the recipe (root, for a
service), so it is refused, as a certificate is (engine.security.tls.foreign_write_access), when it
or its folder belongs to another user or others may write it.
"""

from __future__ import annotations

import os
from importlib import metadata
from pathlib import Path

from engine.hookspecs import PROJECT

PLUGIN_PATH_ENV = "VGR_PLUGIN_PATH"


class PluginEntryError(ValueError):
    """A plugin entry names nothing that may be loaded (the message says why)."""


def installed_plugins() -> list[str]:
    """The names of the entry points of group ``vgr`` installed in this Python."""
    return sorted({ep.name for ep in metadata.entry_points(group=PROJECT)})


def plugin_folders(base: Path) -> list[Path]:
    """Where a plugin named by its file's name is looked for: *base* (the recipe's folder), then the
    folders of ``VGR_PLUGIN_PATH``."""
    listed = [Path(d).expanduser() for d in os.environ.get(PLUGIN_PATH_ENV, "").split(os.pathsep) if d]
    return [base, *listed]


def resolve_plugin(entry: str, base: Path) -> str:
    """*entry* as it is loaded: an installed plugin's name, or a plugin file's absolute path.
    Raises PluginEntryError saying why when it is neither, or the file may not be used."""
    if "/" in entry or entry.endswith(".py"):
        file = (base / Path(entry).expanduser()).resolve()
        if file.suffix != ".py" or not file.is_file():
            raise PluginEntryError(f"plugin file {file} does not exist (a plugin file is a .py file)")
    elif entry in installed_plugins():
        return entry
    else:
        found = [f for d in plugin_folders(base) if (f := (d / f"{entry}.py").resolve()).is_file()]
        if not found:
            raise PluginEntryError(
                f"{entry!r} is neither an installed vgr plugin (entry points of group vgr: "
                f"{', '.join(installed_plugins()) or 'none'}) nor a file {entry}.py next to the recipe "
                f"({base}) or in {PLUGIN_PATH_ENV}; name a plugin file by its path: plugins: [./my_stages.py]"
            )
        file = found[0]
    from engine.security.tls import foreign_write_access

    problems = foreign_write_access(file) + foreign_write_access(file.parent)
    if problems:
        raise PluginEntryError(f"plugin file {file}: {'; '.join(problems)}")
    return str(file)


def is_file_entry(resolved: str) -> bool:
    """Is *resolved* (from :func:`resolve_plugin`) a plugin file rather than an installed plugin?"""
    return resolved.endswith(".py") and Path(resolved).is_absolute()
