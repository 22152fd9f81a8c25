"""What ``--json`` prints: one versioned JSON document per verb outcome, the same on invalid input.

A cell controller or a CI script reads these instead of vgr's text. Each document names its format
(``format``: ``vgr.run/1``, ``vgr.replay/1``, ``vgr.invalid/1``, ``vgr.validate/1``) and carries ``ok``, ``outcome``
and ``exit_code`` (the exit-code table of engine/exit_codes.py). A run's document holds the job's
results as typed fields: ``results`` lists every ``result`` event with its details (a calibration's
verdict and the file of its ``result.json``, a docking evaluation's errors in mm and deg, ...), and
``files`` every file a stage wrote, with its path resolved against the run folder. The JSON Schemas
are shipped beside this module (engine/cli/schemas/) and the tests validate what vgr prints
against them; a change of a document's shape changes its format's version.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from engine.exit_codes import ExitCode
from engine.plain_data import plain
from engine.run.summary import RunSummary

RUN_FORMAT = "vgr.run/1"
INVALID_FORMAT = "vgr.invalid/1"
VALIDATE_FORMAT = "vgr.validate/1"
REPLAY_FORMAT = "vgr.replay/1"  # built by engine/cli/recording.py (also written as the replay folder's replay.json)
SCHEMA_DIR = Path(__file__).with_name("schemas")


def schema(name: str) -> dict[str, Any]:
    """The JSON Schema of document *name* (``run``, ``invalid``, ``validate``)."""
    return json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text())


def files_written(s: RunSummary, event: Any) -> list[tuple[str, Path]]:
    """(label, path) of each file *event* names, resolved against the run folder of *s*."""
    folder = s.artifacts.get("run folder")
    named = (event.details.get("files") or {}).items()
    return [(label, Path(folder, p) if folder and not Path(p).is_absolute() else Path(p)) for label, p in named]


def run_document(s: RunSummary) -> dict[str, Any]:
    """The document of a finished run (``vgr run --json``)."""
    files = [
        {"stage": e.stage, "label": label, "path": str(path)} for e in s.events for label, path in files_written(s, e)
    ]
    doc = {
        "format": RUN_FORMAT,
        "verb": "run",
        "run_id": s.run_id,
        "recipe": s.recipe,
        "process": s.process,
        "ok": s.outcome == "ok",
        "outcome": s.outcome,
        "exit_code": int(s.exit_code),
        "stop_reason": s.stop_reason,
        "wall_s": s.wall_s,
        "artifacts": s.artifacts,
        "files": files,
        "results": [
            {"stage": e.stage, "code": e.code, "message": e.message, "details": e.details}
            for e in s.events
            if e.level == "result"
        ],
        "shared_memory": s.shared_memory,
        "stages": [{**vars(st), "messages_in": st.messages_in, "messages_out": st.messages_out} for st in s.stages],
        "events": [
            {"level": e.level, "stage": e.stage, "code": e.code, "message": e.message, "details": e.details}
            for e in s.events
        ],
    }
    return plain(doc, nan_as_none=True)


def invalid_document(verb: str, error: str, problems: Sequence[Any]) -> dict[str, Any]:
    """The document of a refusal before anything ran: the error and each problem with its place."""
    return {
        "format": INVALID_FORMAT,
        "verb": verb,
        "ok": False,
        "outcome": "invalid",
        "exit_code": int(ExitCode.INVALID),
        "error": error,
        "problems": [vars(p) for p in problems],
    }


def validate_document(recipe: str, stages: int, processes: list[str]) -> dict[str, Any]:
    """The document of a recipe that validates (``vgr validate --json``)."""
    return {
        "format": VALIDATE_FORMAT,
        "verb": "validate",
        "ok": True,
        "outcome": "ok",
        "exit_code": int(ExitCode.OK),
        "recipe": recipe,
        "stages": stages,
        "processes": processes,
    }
