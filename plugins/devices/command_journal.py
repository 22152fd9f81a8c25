"""Idempotent robot command ids: the first reply of each id, kept in memory and optionally on disk.

A device stage asks :meth:`CommandJournal.seen` before executing a command; a known id gets its
first reply back (the stage marks it ``duplicate``) and nothing moves. With a journal file, ids
survive a restart of the run: ``started`` is written (and flushed to disk) *before* the robot is
commanded and ``done`` after, so a command whose run died during the motion is answered as
"outcome unknown, not repeated" instead of moving the robot a second time.

File format: JSON lines ``{"command_id": ..., "phase": "started" | "done", "ok": ..., "error": ...}``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class JournalEntry:
    """What is known about a command id: finished (ok/error) or started with unknown outcome."""

    command_id: str
    finished: bool
    ok: bool
    error: str


class CommandJournal:
    """Command ids already handled by this device (in memory; persisted when *path* is given)."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path else None
        self._entries: dict[str, JournalEntry] = {}
        self._replies: dict[str, object] = {}
        if self.path is not None and self.path.exists():
            self._load(self.path)

    def _load(self, path: Path) -> None:
        for n, line in enumerate(path.read_text().splitlines(), start=1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                cid, phase = str(row["command_id"]), row["phase"]
            except (ValueError, KeyError, TypeError) as exc:
                raise ValueError(f"command journal {path}:{n} is not a journal line ({exc}): {line[:80]!r}") from exc
            if phase == "started":
                self._entries[cid] = JournalEntry(
                    cid, False, False, "command started in an earlier run whose outcome is unknown; not repeated"
                )
            elif phase == "done":
                self._entries[cid] = JournalEntry(cid, True, bool(row.get("ok")), str(row.get("error", "")))

    def seen(self, command_id: str) -> JournalEntry | None:
        return self._entries.get(command_id)

    def first_reply(self, command_id: str) -> object | None:
        """The reply object given the first time in this run (None for ids known only from the file)."""
        return self._replies.get(command_id)

    def start(self, command_id: str) -> None:
        """Mark *command_id* as handled before anything is commanded (durably, when journalling)."""
        self._entries[command_id] = JournalEntry(command_id, False, False, "command in progress")
        self._append({"command_id": command_id, "phase": "started"})

    def finish(self, command_id: str, ok: bool, error: str, reply: object) -> None:
        self._entries[command_id] = JournalEntry(command_id, True, ok, error)
        self._replies[command_id] = reply
        self._append({"command_id": command_id, "phase": "done", "ok": ok, "error": error})

    def _append(self, row: dict[str, object]) -> None:
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a") as f:
            f.write(json.dumps(row, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
