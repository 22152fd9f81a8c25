"""One folder per run and per replay: where everything a run writes goes.

``vgr run`` makes ``runs/<YYYYmmdd-HHMMSS>-<run-id>/`` (``-<process>`` appended for processes other
than ``main``; ``-1``, ``-2`` ... when that name is taken) and ``vgr replay`` makes
``runs/<YYYYmmdd-HHMMSS>-replay-<run-id>/``. A folder is created new (never reused), so nothing a run
or replay wrote is replaced by another. It holds:

* ``<recipe>.mcap``: the recording (unless ``--record FILE`` / ``record.path`` names another file);
* ``recipe.yaml``: the recipe as run (after ``-p`` overrides and ``vars``), with the source named;
* ``run.log``: the engine's and the stages' log at INFO and above (results, warnings, alarms);
* one folder per stage that writes files (``<stage>/``: reports, plots, model files), or the folder
  a stage's own parameter names (a relative one lies inside the run folder).

Stages ask their context for the folder (:meth:`engine.stage.StageContext.output_dir`); the rules
for a folder a parameter names are in :func:`output_dir`.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

from engine.plain_data import plain

if TYPE_CHECKING:
    from engine.recipe.model import LoadedRecipe

DEFAULT_PARENT = "runs"
LOG_NAME = "run.log"
RECIPE_NAME = "recipe.yaml"
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


class OutputDirError(ValueError):
    """A folder a stage parameter names cannot be written: it exists and holds files."""


def safe_name(text: str) -> str:
    """*text* as one file-name component (a run id such as ``a/b`` or ``**`` is not a path)."""
    return _UNSAFE.sub("_", text).strip("._") or "run"


def create(parent: str | Path, name: str) -> Path:
    """A new folder ``<parent>/<stamp>-<name>`` (``-1``, ``-2`` ... if taken), created here and now."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path(parent) / f"{stamp}-{safe_name(name)}"
    base.parent.mkdir(parents=True, exist_ok=True)
    candidate, n = base, 0
    while True:
        try:
            candidate.mkdir()  # atomic: two processes starting in the same second get different folders
            return candidate
        except FileExistsError:
            n += 1
            candidate = base.with_name(f"{base.name}-{n}")


def remove_if_unused(folder: Path) -> None:
    """Remove *folder* made by :func:`create` when nothing but an empty log was written in it (a
    replay or run that could not start leaves no empty folders behind)."""
    log_file = folder / LOG_NAME
    if log_file.is_file() and log_file.stat().st_size == 0:
        log_file.unlink()
    with contextlib.suppress(OSError):
        folder.rmdir()  # only when empty


def run_name(run_id: str, process: str) -> str:
    return run_id if process == "main" else f"{run_id}-{process}"


def write_recipe(folder: Path, loaded: LoadedRecipe) -> Path:
    """``recipe.yaml``: the recipe document as run, headed by its source file and overrides."""
    head = [f"# recipe as run: {loaded.file or '(text)'}"]
    if loaded.overrides:
        head.append(f"# overrides: {' '.join(loaded.overrides)}")
    path = folder / RECIPE_NAME
    body = yaml.safe_dump(plain(loaded.data), sort_keys=False, allow_unicode=True)
    path.write_text("\n".join(head) + "\n" + body)
    return path


@contextmanager
def logging_to(folder: Path, logger: str = "vgr") -> Iterator[Path]:
    """Copy *logger*'s records (INFO and above) into ``<folder>/run.log`` while the block runs."""
    path = folder / LOG_NAME
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setLevel(logging.INFO)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    log = logging.getLogger(logger)
    previous = log.level
    if log.getEffectiveLevel() > logging.INFO:
        log.setLevel(logging.INFO)
    log.addHandler(handler)
    try:
        yield path
    finally:
        log.removeHandler(handler)
        log.setLevel(previous)
        handler.close()


def relative(run_dir: Path, path: str | Path) -> str:
    """*path* relative to *run_dir* when inside it (so a run and its replay name their files alike),
    else as given."""
    p = Path(path)
    try:
        return p.resolve().relative_to(run_dir.resolve()).as_posix()
    except ValueError:
        return str(path)


def new_folder(path: str | Path, what: str) -> Path:
    """The folder a user named for a verb's files (*what*, e.g. ``--report``), created: new, or an
    existing empty folder, never a link. A verb never replaces files it did not create, so a second
    report into the same folder is refused (:class:`OutputDirError`) rather than written over the first."""
    folder = Path(path).expanduser()
    if folder.is_symlink():
        raise OutputDirError(f"{what} {folder} is a link: name a new folder")
    if folder.exists() and not folder.is_dir():
        raise OutputDirError(f"{what} {folder} is a file, not a folder")
    if folder.is_dir() and any(folder.iterdir()):
        raise OutputDirError(
            f"{what} {folder} exists and holds files (an earlier report?): vgr never replaces files it did "
            "not create; name a new folder"
        )
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def output_dir(run_dir: Path | None, stage: str, named: str | Path | None) -> Path | None:
    """The folder stage *stage* writes its files in, created; None when it should write none.

    * nothing named: ``<run_dir>/<stage>/`` (None outside a run folder, e.g. a stage used as a library);
    * a relative path: inside the run folder (outside one: from the working directory);
    * an absolute path, or any path outside a run folder: the user named it, so it must be new or
      empty (:class:`OutputDirError` otherwise): a run never replaces files it did not create.
    """
    if named is None or str(named) == "":
        if run_dir is None:
            return None
        folder = run_dir / safe_name(stage)
    else:
        p = Path(named).expanduser()
        folder = run_dir / p if run_dir is not None and not p.is_absolute() else p
        inside = run_dir is not None and folder.resolve().is_relative_to(run_dir.resolve())
        if not inside and folder.is_dir() and any(folder.iterdir()):
            raise OutputDirError(
                f"stage {stage!r}: folder {folder} exists and holds files; a run never replaces files it "
                "did not create: name a new folder, or a relative one (it then lies inside the run folder)"
            )
        if folder.exists() and not folder.is_dir():
            raise OutputDirError(f"stage {stage!r}: {folder} is a file, not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def output_file(run_dir: Path | None, stage: str, named: str | Path) -> Path:
    """Where stage *stage* writes the file its parameter *named* names, its folder created: a relative
    name lies inside the run folder (outside one: from the working directory); an absolute one is the
    user's and must be new (:class:`OutputDirError`): a run never replaces a file it did not create.
    Write it with engine.files.create_new (exclusive, never through a link)."""
    p = Path(named).expanduser()
    path = run_dir / p if run_dir is not None and not p.is_absolute() else p
    if path.exists() or path.is_symlink():
        raise OutputDirError(
            f"stage {stage!r}: {path} exists; a run never replaces a file it did not create: name a new file, "
            "or a relative one (it then lies inside the run folder)"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    return path
