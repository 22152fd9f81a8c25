"""The recipe's ``serve:`` block (engine.recipe.model.ServeSettings) checked against its graph, and
the versions of the files a service reads (templates, calibrations) that each reply's cycle used."""

from __future__ import annotations

import hashlib
from pathlib import Path

from engine.errors import Problem
from engine.graph import Graph, input_files
from engine.messages import CellReply, Request
from engine.stage import PLAYBACK_ROLES


def serve_problems(graph: Graph) -> list[Problem]:
    """What keeps *graph*'s recipe from being served: no ``serve:`` block, a command whose
    ``stage.service`` does not exist or does not take a Request and reply a CellReply."""
    loaded, serve = graph.loaded, graph.recipe.serve
    if serve is None:
        return [
            loaded.problem(
                ("serve",), "the recipe has no serve: block (cell name and commands): see docs/cell_service.md"
            )
        ]
    problems = []
    for command, target in serve.commands.items():
        where = ("serve", "commands", command)
        stage, _, service = target.partition(".")
        node = graph.nodes.get(stage)
        spec = node.cls.services.get(service) if node is not None else None
        if node is None or spec is None:
            offered = sorted(f"{n}.{s}" for n, nd in graph.nodes.items() for s in nd.cls.services)
            problems.append(
                loaded.problem(where, f"{target!r}: no such stage service (services: {', '.join(offered)})")
            )
        elif spec.request is not Request or spec.reply is not CellReply:
            problems.append(
                loaded.problem(
                    where,
                    f"{target} takes {spec.request.TYPE} and replies {spec.reply.TYPE}: a cell "
                    "command needs a service taking vgr.Request and replying vgr.CellReply",
                )
            )
        elif node.cls.role in PLAYBACK_ROLES:
            problems.append(
                loaded.problem(
                    where, f"{target}: a {node.cls.role} stage cannot answer a job (replay would not re-run it)"
                )
            )
    return problems


def file_version(path: Path) -> str:
    """sha256 of a file, or of a folder's files (names and contents, in sorted order); '' if missing."""
    h = hashlib.sha256()
    if path.is_file():
        h.update(path.read_bytes())
    elif path.is_dir():
        for f in sorted(p for p in path.rglob("*") if p.is_file()):
            h.update(str(f.relative_to(path)).encode() + b"\0")
            h.update(f.read_bytes())
    else:
        return ""
    return h.hexdigest()


def input_versions(graph: Graph, process: str) -> dict[str, dict[str, str]]:
    """``stage.param`` -> {path, sha256} of every file the stages of *process* read."""
    return {
        f"{stage}.{key}": {"path": str(path), "sha256": file_version(path)}
        for stage, key, path in input_files(graph, [process])
    }
