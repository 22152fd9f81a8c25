"""Helpers for engine tests: build a graph from recipe text with the test stages loaded, and write
recipe text without repeating the lines every recipe has.

``header("chain", plugins=["stage_fixtures"], run_id="c1") + stages('''...''')`` is the text of a
recipe: the top-level keys, then ``stages:`` with the given stage entries under it. A test writes
only what its recipe is about; the result is plain recipe YAML (for :func:`graph_from`, a file, or
``str.format``: the header holds no braces of its own).
"""

from __future__ import annotations

import textwrap

from engine.graph import Graph, build_graph
from engine.plugin_manager import load_registry
from engine.recipe.model import load_recipe


def graph_from(text: str, overrides: list[str] | None = None, name: str = "test.yaml") -> Graph:
    loaded = load_recipe(name, overrides, text=textwrap.dedent(text))
    return build_graph(loaded, load_registry(loaded.recipe.plugins))


def header(name: str, **top: object) -> str:
    """``name: NAME``, then one line for each of *top* in the order given (a list as a YAML flow list;
    None left out), then ``stages:``."""
    lines = [f"name: {name}"]
    for key, value in top.items():
        if value is not None:
            lines.append(f"{key}: [{', '.join(map(str, value))}]" if isinstance(value, list) else f"{key}: {value}")
    return "\n".join([*lines, "stages:"]) + "\n"


def stages(*blocks: str) -> str:
    """The stage entries of *blocks* (YAML, each at any common indentation) indented under ``stages:``."""
    return "".join(textwrap.indent(textwrap.dedent(b).strip("\n"), "  ") + "\n" for b in blocks)
