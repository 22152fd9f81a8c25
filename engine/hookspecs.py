"""pluggy hook specifications: how built-in and third-party plugins contribute to vgr.

A plugin is a module (or object) with functions marked ``@hookimpl``; it is found through the
entry-point group ``vgr`` (``[project.entry-points.vgr] myplugin = "my_package.vgr_plugin"``) or
named in a recipe's ``plugins:`` list. vgr's own stages (plugins.builtin) load the same way.
"""

from __future__ import annotations

from typing import Any

import pluggy

PROJECT = "vgr"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


class VgrSpecs:
    @hookspec
    def vgr_stage_types(self) -> list[type]:  # type: ignore[empty-body]
        """Return stage classes (subclasses of engine.stage.Stage) this plugin provides."""

    @hookspec
    def vgr_message_types(self) -> list[type]:  # type: ignore[empty-body]
        """Return message classes (subclasses of engine.messages.Message) this plugin provides."""

    @hookspec
    def vgr_model_effects(self) -> list[Any]:  # type: ignore[empty-body]
        """Return model-effect families for the model-gap workflow's catalog (``vgr gap``).

        Each item is an effect family (:class:`plugins.model_gap.core.interfaces.EffectFamily`) or a class
        instantiated without arguments: ``name`` (unique across all plugins: a duplicate is an error),
        ``description``, ``requires`` and ``candidates(problem)`` returning one candidate per place the
        effect can act (``docs/model_gap.md``).
        """
