"""Helpers for engine tests: build a graph from recipe text with the test stages loaded."""

from __future__ import annotations

import textwrap

from engine.graph import Graph, build_graph
from engine.plugin_manager import load_registry
from engine.recipe import load_recipe


def graph_from(text: str, overrides: list[str] | None = None, name: str = "test.yaml") -> Graph:
    loaded = load_recipe(name, overrides, text=textwrap.dedent(text))
    return build_graph(loaded, load_registry(loaded.recipe.plugins))
