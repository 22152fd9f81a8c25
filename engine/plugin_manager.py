"""Discovering plugins and holding the registry of stage types, message types and model effects,
and the verbs plugins add to the ``vgr`` command (:func:`plugin_verbs`).

``load_registry()`` builds a pluggy PluginManager, loads every entry point of group ``vgr``
(including vgr's own ``plugins.builtin``) plus the plugin files a recipe names (what an entry may
name: engine.recipe.plugin_entries), and collects what the hooks return. Two plugins claiming one
stage type name, or one model-effect name, is an error that names both.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import pluggy

from engine.hookspecs import PROJECT, CliVerb, VgrSpecs
from engine.messages import Message, codec
from engine.recipe.plugin_entries import PluginEntryError, is_file_entry, resolve_plugin
from engine.stage import EVENTS_PORT, Stage


class PluginError(RuntimeError):
    """A plugin could not be loaded or declares something invalid."""


@dataclass
class Registry:
    """Everything the loaded plugins provide."""

    stages: dict[str, type[Stage]] = field(default_factory=dict)
    stage_origin: dict[str, str] = field(default_factory=dict)
    effects: dict[str, Any] = field(default_factory=dict)  # model-gap effect families by name
    effect_origin: dict[str, str] = field(default_factory=dict)
    plugins: list[str] = field(default_factory=list)

    def stage(self, type_name: str) -> type[Stage]:
        return self.stages[type_name]


def _check_stage(cls: Any, origin: str) -> None:
    if not (isinstance(cls, type) and issubclass(cls, Stage)):
        raise PluginError(f"plugin {origin} returned {cls!r}, which is not a Stage subclass")
    if not cls.type_name:
        raise PluginError(f"stage class {cls.__module__}.{cls.__name__} (plugin {origin}) has no type_name")
    if EVENTS_PORT in cls.outputs:
        raise PluginError(f"stage {cls.type_name}: output port name {EVENTS_PORT!r} is reserved")
    for kind, ports in (("input", cls.inputs), ("output", cls.outputs)):
        for port, mtype in ports.items():
            if not (isinstance(mtype, type) and issubclass(mtype, Message)):
                raise PluginError(f"stage {cls.type_name}: {kind} port {port!r} type {mtype!r} is not a Message")


def load_plugin_file(file: Path) -> ModuleType:
    """The module of plugin file *file* (absolute, checked by engine.recipe.plugin_entries), loaded
    once under its file's name."""
    name = file.stem
    loaded = sys.modules.get(name)
    if loaded is not None:
        if Path(getattr(loaded, "__file__", "") or "").resolve() == file:
            return loaded
        raise PluginError(f"plugin file {file}: a module named {name!r} is already loaded from {loaded.__file__}")
    spec = importlib.util.spec_from_file_location(name, file)
    if spec is None or spec.loader is None:
        raise PluginError(f"plugin file {file} cannot be loaded as a module")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # (its stages' classes are found by module name, as any module's)
    try:
        spec.loader.exec_module(mod)
    except Exception as exc:
        del sys.modules[name]
        raise PluginError(f"cannot load plugin file {file}: {exc}") from exc
    return mod


def _plugin_manager(extra: Iterable[str], entry_points: bool) -> pluggy.PluginManager:
    """A PluginManager with the entry points of group ``vgr`` (vgr's own included) and the *extra*
    plugins, each an installed plugin's name or a plugin file (engine.recipe.plugin_entries; a
    relative file from the current folder)."""
    pm = pluggy.PluginManager(PROJECT)
    pm.add_hookspecs(VgrSpecs)
    if entry_points:
        pm.load_setuptools_entrypoints(PROJECT)
    for entry in extra:
        try:
            resolved = resolve_plugin(entry, Path.cwd())
        except PluginEntryError as exc:
            raise PluginError(str(exc)) from None
        if not is_file_entry(resolved):
            if not entry_points:
                pm.load_setuptools_entrypoints(PROJECT, name=resolved)
            continue
        mod = load_plugin_file(Path(resolved))
        if not pm.is_registered(mod):
            pm.register(mod, name=mod.__name__)
    if entry_points and "builtin" not in {name for name, _ in pm.list_name_plugin()}:
        raise PluginError(
            "vgr's built-in plugins are not registered: install vgr (`make install` or `pip install -e .`)"
        )
    return pm


def plugin_verbs(taken: Iterable[str] = ()) -> dict[str, CliVerb]:
    """The verbs the installed plugins add to ``vgr``, by name; *taken* are the engine's own verbs.
    Imports only the plugins' entry-point modules, not the verbs' modules."""
    pm = _plugin_manager((), entry_points=True)
    owner = dict.fromkeys(taken, "the engine")
    verbs: dict[str, CliVerb] = {}
    for impl in pm.hook.vgr_cli_verbs.get_hookimpls():
        for verb in impl.function() or []:
            if not isinstance(verb, CliVerb):
                raise PluginError(f"plugin {impl.plugin_name} returned {verb!r} as a verb: expected a CliVerb")
            if verb.name in owner:
                raise PluginError(
                    f"verb {verb.name!r} is provided twice: by {owner[verb.name]} and by plugin {impl.plugin_name}"
                )
            owner[verb.name] = f"plugin {impl.plugin_name}"
            verbs[verb.name] = verb
    return verbs


def cell_gateways() -> dict[str, str]:
    """The gateways the installed plugins offer a cell service: name -> module (hook vgr_cell_gateways)."""
    pm = _plugin_manager((), entry_points=True)
    found: dict[str, str] = {}
    for impl in pm.hook.vgr_cell_gateways.get_hookimpls():
        for gw in impl.function() or []:
            if gw.name in found:
                raise PluginError(f"cell gateway {gw.name!r} is provided twice (plugin {impl.plugin_name})")
            found[gw.name] = gw.module
    return found


def load_registry(extra: Iterable[str] = (), *, entry_points: bool = True) -> Registry:
    """Load plugins (entry points of group ``vgr`` + *extra*: installed plugins' names or plugin
    files, as a recipe's ``plugins:`` lists them) and build the registry."""
    pm = _plugin_manager(extra, entry_points)
    reg = Registry(plugins=sorted(name for name, _ in pm.list_name_plugin() if name))
    for impl in pm.hook.vgr_message_types.get_hookimpls():
        for mtype in impl.function() or []:
            if not (isinstance(mtype, type) and issubclass(mtype, Message)):
                raise PluginError(f"plugin {impl.plugin_name} returned {mtype!r} as a message type")
            codec.registry.add(mtype)
    for impl in pm.hook.vgr_stage_types.get_hookimpls():
        for cls in impl.function() or []:
            _check_stage(cls, impl.plugin_name)
            prev = reg.stage_origin.get(cls.type_name)
            if prev is not None and reg.stages[cls.type_name] is not cls:
                raise PluginError(
                    f"stage type {cls.type_name!r} is provided twice: by plugin {prev} and by {impl.plugin_name}"
                )
            reg.stages[cls.type_name] = cls
            reg.stage_origin[cls.type_name] = impl.plugin_name
    for impl in pm.hook.vgr_model_effects.get_hookimpls():
        for eff in impl.function() or []:
            name = getattr(eff, "name", None)
            if not (isinstance(name, str) and name and callable(getattr(eff, "candidates", None))):
                raise PluginError(
                    f"plugin {impl.plugin_name} returned {eff!r} as a model effect: an effect family needs a "
                    "non-empty `name` and a `candidates(problem)` method (see engine.hookspecs, vgr_model_effects)"
                )
            prev = reg.effect_origin.get(name)
            if prev is not None and reg.effects[name] is not eff:
                raise PluginError(
                    f"model effect {name!r} is provided twice: by plugin {prev} and by {impl.plugin_name} "
                    "(effect names must be unique: rename one)"
                )
            reg.effects[name] = eff
            reg.effect_origin[name] = impl.plugin_name
    return reg
