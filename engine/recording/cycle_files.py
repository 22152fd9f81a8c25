"""Rolling recordings of a cell service: every cycle (or every N) in an MCAP file of its own.

Files, in the service's run folder under ``cycles/``:

* ``start.mcap``: from the start to the service being ready (set-up events, first states);
* ``cycle-<first cycle, 7 digits>.mcap``: first the last frame tree and scene of each topic (published
  once at start-up, they would otherwise be in ``start.mcap`` only), then the next
  ``serve.record.cycles_per_file`` cycles and what happened between them and the previous file
  (robot moves the controller made, streams). A file is finished (index, footer, ``vgr.cycles``
  metadata: each cycle's number, command, id, status) right after the reply of its last cycle, so a
  finished cycle is safe on disk whatever happens next; a kill mid-cycle leaves that one file
  unindexed (``vgr recover`` restores it). A reload finishes the file early, so every file holds
  cycles of one configuration.

Each file is self-contained, as a run's recording is (engine.recording.recorder): the recipe text with
the overrides in effect (a reload's included), the versions of vgr and its libraries, and
``vgr.inputs``: path and sha256 of every file the stages read (templates, calibrations). ``vgr replay``
of one file re-runs its cycles through the re-run stages and compares every reply bit for bit.

Retention: after each finished file, the oldest files this recorder wrote go while there are more
than ``keep_files``, more than ``keep_mb`` in all, or (``keep_hours`` > 0) older than that. Only
files it created itself are ever removed.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from engine.recipe.model import CycleRecordSettings, LoadedRecipe, RecordSettings
from engine.recording.recorder import Recorder
from engine.run.runner import Runner, RunSummary
from engine.stage import PLAYBACK_ROLES
from engine.transport.bus import topic_of

log = logging.getLogger("vgr.cell.cycles")
# published once (a robot's base, a camera's mount, the workpiece meshes): each file starts with the
# last of each, so it draws the cell's frame tree and scene on its own (a viewer, a reader)
LATCHED_TYPES = frozenset({"FrameTransforms", "SceneMeshes"})
CYCLES_FOLDER = "cycles"


def cycle_file_name(first_cycle: int) -> str:
    return f"cycle-{first_cycle:07d}.mcap"


class CycleRecorder(Recorder):
    """A run observer writing ``<folder>/start.mcap``, then one file per ``cycles_per_file`` cycles."""

    def __init__(
        self,
        folder: Path,
        settings: RecordSettings,
        rolling: CycleRecordSettings,
        loaded: LoadedRecipe,
        plugins: list[str],
        inputs: Callable[[], dict[str, Any]],
    ) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        super().__init__(folder / "start.mcap", settings, loaded, plugins)
        self.folder = folder
        self.rolling = rolling
        self.inputs = inputs  # the input files' versions now (engine.run.cell.settings.input_versions)
        self._cycles: list[dict[str, Any]] = []  # cycles in the open file
        self._next_cycle = 1
        self._written: deque[tuple[Path, float]] = deque()  # finished files (path, finished at), oldest first
        self._lock = threading.Lock()
        self.files_removed = 0
        self._latched: dict[str, tuple[Any, ...]] = {}  # topic -> its last FrameTransforms / SceneMeshes

    def on_start(self, runner: Runner) -> None:
        self._runner = runner
        super().on_start(runner)

    # -- what the service tells it (any thread) ------------------------------------------------
    def roll(self, loaded: LoadedRecipe | None = None) -> None:
        """Finish the open file and open the next (after *loaded*, a reload's recipe, takes effect)."""
        self._q.put(("roll", loaded))

    def cycle_done(self, info: dict[str, Any]) -> None:
        """Cycle *info* (number, command, id, status) was answered: its file is finished when full."""
        self._q.put(("cycle_done", info))

    def files(self) -> list[Path]:
        with self._lock:
            return [p for p, _ in self._written]

    # -- writer thread ---------------------------------------------------------------------------
    def _write(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "roll":
            if item[1] is not None:
                self.loaded = item[1]
            self._next_file()
        elif kind == "cycle_done":
            self._cycles.append(item[1])
            self._next_cycle = int(item[1]["cycle"]) + 1
            if len(self._cycles) >= self.rolling.cycles_per_file:
                self._next_file()
        else:
            super()._write(item)
            if item[0] in ("msg", "remote") and item[3] in LATCHED_TYPES and self._played_back(item[1]):
                self._latched[topic_of(item[1], item[2])] = item

    def _played_back(self, stage: str) -> bool:
        """A stage replay feeds from the file (its messages may open every file; a re-run stage's may not)."""
        assert self._runner is not None
        cls = self._runner.graph.nodes[stage].cls
        return cls.role in PLAYBACK_ROLES or cls.is_source()

    def _next_file(self) -> None:
        self._finish_current()
        path = self.folder / cycle_file_name(self._next_cycle)
        n = 1
        while path.exists() or path.is_symlink():  # (a reload finished a file before its first cycle)
            path = self.folder / f"{Path(cycle_file_name(self._next_cycle)).stem}-{n}.mcap"
            n += 1
        self.path = path
        self._seen_remote.clear()  # (messages from other processes are written once per file)
        self._open_file(path, {"vgr.inputs": {"json": json.dumps(self.inputs())}})
        now = self._now()
        for item in list(self._latched.values()):  # the frame tree and the scene, as they are now
            kind, stage, port, type_name, _, stamp, seq, payload = item
            super()._write((kind, stage, port, type_name, now, stamp, seq, payload))

    def _finish_current(self) -> None:
        self._finish_with({"ok": "true", "outcome": "ok", "stop_reason": "", "recording_error": self.error or ""})

    def _close(self, summary: RunSummary) -> None:
        self._finish_with(self._summary_record(summary))

    def _finish_with(self, summary: dict[str, str]) -> None:
        """Finish the open file with *summary* and its cycles (``vgr.summary``), then apply the retention."""
        cycles, self._cycles = self._cycles, []
        self._finish_file({**summary, "cycles": json.dumps(cycles)})
        with self._lock:
            self._written.append((self.path, time.time()))
        self._retain()

    def _retain(self) -> None:
        """Remove the oldest finished files beyond the retention limits (never the open one)."""
        r = self.rolling
        with self._lock:
            sizes = {p: _size(p) for p, _ in self._written}
            total = sum(sizes.values())
            now = time.time()
            while self._written:
                path, finished = self._written[0]
                too_many = r.keep_files and len(self._written) > r.keep_files
                too_big = r.keep_mb and total > r.keep_mb * 1e6
                too_old = r.keep_hours and now - finished > r.keep_hours * 3600
                if not (too_many or too_big or too_old):
                    break
                self._written.popleft()
                total -= sizes.get(path, 0)
                try:
                    path.unlink()
                    self.files_removed += 1
                except OSError as exc:
                    log.warning("could not remove the old cycle recording %s: %s", path, exc)

    def on_finish(self, runner: Runner, summary: RunSummary) -> None:
        self._q.put(("end", summary))
        if self._thread is not None:
            self._thread.join(60.0)
            if self._thread.is_alive():
                self.error = self.error or "the cycle recorder did not finish within 60 s"
        summary.artifacts["recordings"] = str(self.folder)
        if self.error:
            summary.artifacts["recording_error"] = self.error


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
