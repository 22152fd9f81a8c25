"""The engine's modules import each other without a circle, counting imports under TYPE_CHECKING.

The runner owns processes and a run's lifetime; a stage's runtime reaches it only through the
protocols of engine.run.stage_host, and the ports reach their runtime the same way. A module that
imported its owner again (even only for a type annotation) would tie the pieces back into one, so
this test reads every ``engine/*.py`` with ``ast`` (no import runs) and fails on any cycle.
"""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

ENGINE = Path(__file__).resolve().parents[2] / "engine"


def engine_imports(path: Path) -> set[str]:
    """The ``engine.<module>`` names (top-level modules of engine/) that *path* imports anywhere:
    at module level, in functions, and in ``if TYPE_CHECKING:`` blocks."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            # `from engine import codec` imports the module engine.messages.codec
            names = [f"{node.module}.{a.name}" for a in node.names] if node.module == "engine" else [node.module]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] == "engine" and len(parts) > 1 and (ENGINE / f"{parts[1]}.py").is_file():
                found.add(parts[1])
    return found


def import_graph() -> dict[str, set[str]]:
    return {p.stem: engine_imports(p) - {p.stem} for p in sorted(ENGINE.glob("*.py")) if p.stem != "__init__"}


def test_engine_modules_import_each_other_without_a_cycle():
    graph = import_graph()
    assert {"runner", "runtime", "output_port", "remote_input", "stage_host"} <= set(graph)
    try:
        order = list(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        raise AssertionError(f"engine modules import each other in a circle: {' -> '.join(exc.args[1])}") from None
    assert order.index("runtime") < order.index("runner")  # the runner depends on the runtime, not back


def test_the_graph_sees_imports_under_type_checking(tmp_path):
    mod = tmp_path / "m.py"
    mod.write_text(
        "from typing import TYPE_CHECKING\n"
        "from engine import codec\n"
        "if TYPE_CHECKING:\n"
        "    from engine.run.runner import Runner\n"
        "def f():\n"
        "    import engine.graph\n"
    )
    assert engine_imports(mod) == {"codec", "runner", "graph"}
