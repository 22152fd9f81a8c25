"""pluggy hook specifications: how built-in and third-party plugins contribute to vgr.

A plugin is a module (or object) with functions marked ``@hookimpl``; it is found through the
entry-point group ``vgr`` (``[project.entry-points.vgr] myplugin = "my_package.vgr_plugin"``) or
a plugin file named in a recipe's ``plugins:`` list (engine.recipe.plugin_entries). vgr's own
stages (plugins.builtin) load the same way.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import pluggy

PROJECT = "vgr"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


class CliVerb(NamedTuple):
    """A verb a plugin adds to the ``vgr`` command (hook ``vgr_cli_verbs``)."""

    name: str  # the verb: ``vgr <name> ...``
    help: str  # one line for ``vgr --help``
    module: str  # imported only when the verb runs; its ``add_verbs(subparsers)`` adds the full parser


class CellGateway(NamedTuple):
    """A way for controllers to reach a cell service besides zenoh (hook ``vgr_cell_gateways``)."""

    name: str  # the key of the recipe's ``serve.gateways`` block that starts it
    module: str  # imported when a served recipe names it; ``start_gateway(handle, settings, log)``


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

    @hookspec
    def vgr_cli_verbs(self) -> list[CliVerb]:  # type: ignore[empty-body]
        """Return the verbs this plugin adds to ``vgr`` (:class:`CliVerb`). A verb's module is imported
        only when that verb runs, so ``vgr --help`` and ``vgr run`` do not pay for every capability's
        libraries; its ``add_verbs(subparsers)`` adds the parser, whose ``func`` returns an exit code of
        engine.exit_codes. A verb name that another plugin or the engine already has is an error.
        """

    @hookspec
    def vgr_cell_gateways(self) -> list[CellGateway]:  # type: ignore[empty-body]
        """Return the gateways this plugin offers a cell service (:class:`CellGateway`). A served recipe's
        ``serve.gateways: {<name>: {settings}}`` starts gateway *name*: its module's
        ``start_gateway(handle, settings, log)`` gets ``handle(command, request_document) -> reply
        document`` (engine.run.cell.protocol) and returns an object with ``close()`` and ``address``;
        bad settings raise ValueError.
        """
