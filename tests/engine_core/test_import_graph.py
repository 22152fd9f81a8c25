"""The layout's rules, read from the code with ``ast`` (no import runs), over engine/ and plugins/:

- no import circle anywhere, counting imports inside functions and under ``TYPE_CHECKING`` (a module
  that imported its importer again, even for an annotation, would tie the two back into one);
- the engine's layers: its top level, ``messages``, ``recipe`` and ``security`` < ``transport`` <
  ``run`` < ``recording`` < ``cli``; a module imports only from its own layer or below;
- the engine never imports ``plugins``;
- the simulated cell (``plugins.sim``) is imported only by itself and by the plugin that registers
  its stages (``plugins.builtin``): tests and benchmarks use it, the product does not;
- the model-gap core (``plugins.model_gap.core``) imports no robot code, nothing of plugins but itself;
- the recording reader loads neither zenoh nor the runner (checked by importing it in a subprocess).

``from a.b import c`` counts as importing ``a.b.c`` when that is a module, else ``a.b``. Importing
``a.b.c`` does not count as importing the package ``a.b`` (Python runs ``a/b/__init__.py`` first,
but a package's ``__init__`` that re-exports its modules is not a circle of the code's design).
"""

from __future__ import annotations

import ast
import graphlib
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LAYERS = {"transport": 1, "run": 2, "recording": 3, "cli": 4}  # any other engine module: 0


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for top in ("engine", "plugins") for p in sorted((root / top).rglob("*.py"))}


def imports_of(path: Path, known: set[str]) -> set[str]:
    """The modules of *known* that *path* imports anywhere: at module level, in functions, and in
    ``if TYPE_CHECKING:`` blocks."""

    def resolve(name: str) -> str | None:
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    found: set[str | None] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found |= {resolve(a.name) for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                found.add(full if full in known else resolve(node.module))
    found.discard(None)
    return found  # type: ignore[return-value]


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    mods = modules(root)
    known = set(mods)
    return {name: imports_of(path, known) - {name} for name, path in mods.items()}


def layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS.get(parts[1], 0) if len(parts) > 1 else 0


def violations(graph: dict[str, set[str]]) -> list[str]:
    out = []
    for mod, deps in sorted(graph.items()):
        for dep in sorted(deps):
            if mod.startswith("engine") and dep.startswith("plugins"):
                out.append(f"{mod} -> {dep}: the engine imports a plugin")
            if mod.startswith("engine") and dep.startswith("engine") and layer(dep) > layer(mod):
                out.append(f"{mod} -> {dep}: a lower layer of the engine imports a higher one")
            if dep.startswith("plugins.sim") and not mod.startswith(("plugins.sim", "plugins.builtin")):
                out.append(f"{mod} -> {dep}: only the simulated cell and plugins.builtin import plugins.sim")
            if (
                mod.startswith("plugins.model_gap.core")
                and dep.startswith("plugins")
                and not dep.startswith("plugins.model_gap.core")
            ):
                out.append(f"{mod} -> {dep}: the model-gap core imports plugin code")
    return out


def test_no_import_circle_in_the_whole_tree():
    graph = import_graph()
    assert {"engine.run.runner", "engine.run.runtime", "plugins.builtin", "plugins.model_gap.core.workflow"} <= set(
        graph
    )
    try:
        order = list(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        raise AssertionError(f"modules import each other in a circle: {' -> '.join(exc.args[1])}") from None
    assert order.index("engine.run.runtime") < order.index("engine.run.runner")  # the runner uses the runtime


def test_the_layers_hold():
    assert violations(import_graph()) == []


def test_the_rules_see_a_violation_and_a_circle(tmp_path):
    """The checks above can fail: a small tree with one of each breaks every rule."""
    files = {
        "engine/__init__.py": "",
        "engine/run/__init__.py": "",
        "engine/run/a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from engine.cli.b import X\n",
        "engine/cli/__init__.py": "",
        "engine/cli/b.py": "def f():\n    from engine.run import a\n",
        "engine/transport/__init__.py": "",
        "engine/transport/c.py": "import plugins.sim.cell\n",
        "plugins/__init__.py": "",
        "plugins/sim/__init__.py": "",
        "plugins/sim/cell.py": "",
        "plugins/model_gap/core/__init__.py": "",
        "plugins/model_gap/core/w.py": "from plugins.robot import kinematics\n",
        "plugins/robot/__init__.py": "",
        "plugins/robot/kinematics.py": "",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    graph = import_graph(tmp_path)
    assert graph["engine.run.a"] == {"engine.cli.b"} and graph["engine.cli.b"] == {"engine.run.a"}
    found = violations(graph)
    assert any("lower layer" in v for v in found)
    assert any("the engine imports a plugin" in v for v in found)
    assert any("only the simulated cell" in v for v in found)
    assert any("model-gap core imports plugin code" in v for v in found)
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError:
        pass
    else:
        raise AssertionError("the circle engine.run.a <-> engine.cli.b was not seen")


def test_the_recording_reader_loads_neither_zenoh_nor_the_runner():
    code = (
        "import sys, engine.recording.reader\n"
        "print(sorted(m for m in sys.modules if m == 'zenoh' or m.startswith(('engine.run', 'engine.transport'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", out.stdout


def test_the_layout_stays_navigable():
    """At most 15 modules at the engine's top level; no package directly under engine/ or plugins/
    holds more than a third of their lines."""
    top = [p for p in (ROOT / "engine").glob("*.py")]
    assert len(top) <= 15, sorted(p.name for p in top)
    lines = {
        d: sum(len(p.read_text(encoding="utf-8").splitlines()) for p in d.rglob("*.py"))
        for base in ("engine", "plugins")
        for d in (ROOT / base).iterdir()
        if d.is_dir() and d.name != "__pycache__"
    }
    total = sum(len(p.read_text(encoding="utf-8").splitlines()) for p in modules().values())
    biggest = max(lines, key=lines.__getitem__)
    assert lines[biggest] <= total / 3, f"{biggest.relative_to(ROOT)}: {lines[biggest]} of {total} lines"
