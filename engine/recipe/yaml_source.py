"""YAML loading that remembers where every key came from, for error messages with line numbers.

``load_with_locations(text)`` returns the plain data (dicts, lists, scalars, as yaml.safe_load
would) and a map from key paths (tuples of str keys / int indices) to 1-based (line, column).
Duplicate keys, which PyYAML silently overwrites, are reported as errors. Aliases are expanded
into plain copies, with a budget of :data:`MAX_NODES` so that an alias "bomb" is an error, not a hang.
"""

from __future__ import annotations

from typing import Any

import yaml

from engine.errors import Problem, RecipeError

Path = tuple[str | int, ...]
MAX_NODES = 100_000
Locations = dict[Path, tuple[int, int]]


def _mark(node: yaml.Node) -> tuple[int, int]:
    return node.start_mark.line + 1, node.start_mark.column + 1


class _Builder:
    def __init__(self, file: str | None) -> None:
        self.loader = yaml.SafeLoader("")
        self.file = file
        self.locations: Locations = {}
        self.problems: list[Problem] = []
        self.count = 0

    def _key_problem(self, message: str, path: Path, knode: yaml.Node) -> None:
        line, col = _mark(knode)
        self.problems.append(Problem(message, ".".join(map(str, path)), self.file, line, col))

    def build(self, node: yaml.Node, path: Path, depth: int = 0) -> Any:
        self.count += 1
        if self.count > MAX_NODES:
            raise RecipeError(
                [
                    Problem(
                        f"the recipe expands to more than {MAX_NODES} values (YAML aliases?)",
                        file=self.file,
                        line=_mark(node)[0],
                    )
                ]
            )
        if depth > 100:
            raise RecipeError([Problem("nesting deeper than 100 levels", file=self.file, line=_mark(node)[0])])
        if isinstance(node, yaml.MappingNode):
            self.loader.flatten_mapping(node)
            out: dict[Any, Any] = {}
            for knode, vnode in node.value:
                key = self.loader.construct_object(knode, deep=True)
                if not isinstance(key, str | int | float | bool) or key is None:
                    self._key_problem("mapping keys must be plain scalars", path, knode)
                    continue
                key = str(key) if not isinstance(key, str) else key
                sub = (*path, key)
                if key in out:
                    self._key_problem(f"duplicate key {key!r} (the first one would be silently lost)", sub, knode)
                    continue
                self.locations[sub] = _mark(knode)
                out[key] = self.build(vnode, sub, depth + 1)
            return out
        if isinstance(node, yaml.SequenceNode):
            items = []
            for i, item in enumerate(node.value):
                self.locations[(*path, i)] = _mark(item)
                items.append(self.build(item, (*path, i), depth + 1))
            return items
        return self.loader.construct_object(node, deep=True)


def load_with_locations(text: str, file: str | None = None) -> tuple[Any, Locations]:
    """Parse *text*; raise RecipeError (with line/column) on syntax errors or duplicate keys."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        msg = f"YAML syntax error: {exc.problem or exc.context or exc}"
        raise RecipeError(
            [
                Problem(
                    msg,
                    file=file,
                    line=mark.line + 1 if mark else None,
                    column=mark.column + 1 if mark else None,
                )
            ]
        ) from None
    except (yaml.YAMLError, RecursionError, ValueError) as exc:
        raise RecipeError([Problem(f"YAML error: {exc}", file=file)]) from None
    if node is None:
        return None, {}
    builder = _Builder(file)
    try:
        data = builder.build(node, ())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise RecipeError(
            [
                Problem(
                    f"YAML error: {getattr(exc, 'problem', None) or exc}",
                    file=file,
                    line=mark.line + 1 if mark else None,
                )
            ]
        ) from None
    except (RecursionError, ValueError, TypeError, OverflowError) as exc:
        raise RecipeError([Problem(f"YAML error: {exc}", file=file)]) from None
    if builder.problems:
        raise RecipeError(builder.problems)
    builder.locations[()] = _mark(node)
    return data, builder.locations


def locate(locations: Locations, path: Path) -> tuple[int | None, int | None]:
    """Location of *path*, or of its nearest ancestor that has one."""
    p = tuple(path)
    while p:
        if p in locations:
            return locations[p]
        p = p[:-1]
    return locations.get((), (None, None))
