"""A real `vgr serve` of the simulated cell (recipes/cell_service_sim.yaml) in a child process, for the
tests of the cell service: a recipe copy of its own (cell name, gateways, security), its own private
socket folder (XDG_RUNTIME_DIR), bounded waits, and the child killed whatever happens."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from engine.messages import Request
from engine.run.cell.client import CellClient, CellUnreachableError
from engine.run.cell.protocol import pose_doc

ROOT = Path(__file__).resolve().parents[2]
SIM_RECIPE = ROOT / "recipes" / "cell_service_sim.yaml"
TEMPLATE = ROOT / "recipes" / "templates" / "eye_in_hand.vgrtpl"
SCHEMA_FILE = ROOT / "engine" / "run" / "cell" / "schemas" / "cell_api.schema.json"
READY_S = 60.0  # start-up takes ~8-10 s on a 2-core machine


def private_runtime_dir() -> Path:
    """A short XDG_RUNTIME_DIR of its own, mode 0700 (a unix socket's path has at most 107 bytes)."""
    folder = Path(tempfile.mkdtemp(prefix="vgr-xdg-", dir="/tmp"))
    folder.chmod(0o700)
    return folder


def write_recipe(
    folder: Path,
    cell: str,
    *,
    serve: dict[str, Any] | None = None,
    top: dict[str, Any] | None = None,
) -> Path:
    """A copy of the simulated cell's recipe in *folder*, serving cell *cell*, the template by its
    absolute path; *serve* adds to its ``serve:`` block, *top* sets top-level keys (security, processes)."""
    data = yaml.safe_load(SIM_RECIPE.read_text())
    data["vars"]["template"] = str(TEMPLATE)
    data["serve"]["cell"] = cell
    data["serve"].update(serve or {})
    data.update(top or {})
    path = folder / f"{cell}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def vgr(*args: str) -> list[str]:
    return [sys.executable, "-m", "engine.cli.main", *args]


def child_env(runtime_dir: Path) -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = os.pathsep.join([str(ROOT / "tests"), str(ROOT), e.get("PYTHONPATH", "")])
    e["XDG_RUNTIME_DIR"] = str(runtime_dir)
    e["COLUMNS"] = "250"  # rich wraps the ready line at 80 columns otherwise
    return e


@contextlib.contextmanager
def runtime_env(runtime_dir: Path) -> Iterator[None]:
    """XDG_RUNTIME_DIR of this process set to *runtime_dir* for a while (a CellClient looks for the
    cell's socket there when it is made)."""
    before = os.environ.get("XDG_RUNTIME_DIR")
    os.environ["XDG_RUNTIME_DIR"] = str(runtime_dir)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("XDG_RUNTIME_DIR", None)
        else:
            os.environ["XDG_RUNTIME_DIR"] = before


class Server:
    """`vgr serve RECIPE` (or another process of it) in a child; its output in files of *folder*."""

    def __init__(
        self, recipe: Path, cell: str, folder: Path, runtime_dir: Path, *extra: str, process: str = "main"
    ) -> None:
        self.recipe, self.cell, self.folder, self.runtime_dir = recipe, cell, folder, runtime_dir
        self.runs_dir = folder / f"runs-{process}"
        self.out_path = folder / f"{cell}-{process}.out"
        self.err_path = folder / f"{cell}-{process}.err"
        cmd = vgr("serve", str(recipe), "--runs-dir", str(self.runs_dir), *extra)
        if process != "main":
            cmd += ["--process", process]
        with self.out_path.open("w") as out, self.err_path.open("w") as err:
            self.proc = subprocess.Popen(cmd, env=child_env(runtime_dir), cwd=folder, stdout=out, stderr=err)

    # -- output ----------------------------------------------------------------------------------
    def out(self) -> str:
        return self.out_path.read_text(errors="replace")

    def err(self) -> str:
        return self.err_path.read_text(errors="replace")

    def output(self) -> str:
        return f"--- stdout\n{self.out()}\n--- stderr\n{self.err()[-6000:]}"

    @property
    def run_dir(self) -> Path:
        """The service's run folder (the only one under its runs folder)."""
        [folder] = [p for p in self.runs_dir.iterdir() if p.is_dir()]
        return folder

    def cycle_lines(self) -> list[dict[str, Any]]:
        path = self.run_dir / "cycles.jsonl"
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]

    def gateway_address(self, name: str = "tcp", timeout_s: float = READY_S) -> tuple[str, int]:
        """host, port of gateway *name* from the ready line on stderr."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            found = re.search(rf"{name} gateway on ([0-9.]+):(\d+)", " ".join(self.err().split()))
            if found:
                return found.group(1), int(found.group(2))
            assert self.proc.poll() is None, self.output()
            time.sleep(0.1)
        raise AssertionError(f"no '{name} gateway on' line within {timeout_s:g} s\n{self.output()}")

    # -- clients -------------------------------------------------------------------------------
    def client(self, **kw: Any) -> CellClient:
        """A client of the cell on its private socket (an error when it is not serving)."""
        kw.setdefault("connect_timeout_s", 5.0)
        kw.setdefault("timeout_s", 60.0)
        with runtime_env(self.runtime_dir):
            return CellClient(self.cell, **kw)

    def wait_ready(self, timeout_s: float = READY_S, **kw: Any) -> CellClient:
        """A client once the cell serves (polled, *timeout_s* at most)."""
        deadline = time.monotonic() + timeout_s
        while True:
            assert self.proc.poll() is None, f"vgr serve ended ({self.proc.returncode})\n{self.output()}"
            try:
                return self.client(connect_timeout_s=2.0, **kw)
            except CellUnreachableError as exc:
                if time.monotonic() > deadline:
                    raise AssertionError(
                        f"cell {self.cell} not serving after {timeout_s:g} s\n{self.output()}"
                    ) from exc
                time.sleep(0.2)

    # -- the end -------------------------------------------------------------------------------
    def send(self, signum: int = signal.SIGINT) -> None:
        self.proc.send_signal(signum)

    def wait(self, timeout_s: float = 60.0) -> int:
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"vgr serve still running after {timeout_s:g} s\n{self.output()}") from None

    def stop(self, signum: int = signal.SIGINT, timeout_s: float = 60.0) -> int:
        if self.proc.poll() is None:
            self.send(signum)
        return self.wait(timeout_s)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(30)


# -- the simulated devices, over their stage services (as plugins.sim.cell_controller does) ---------
def place(sim: Any, T: Any, part: str = "part") -> None:
    sim._device(sim.camera, "place", Request(command="place", args={"part": part, "pose": pose_doc(T)}))


def camera_fault(sim: Any, **args: Any) -> None:
    sim._device(sim.camera, "fault", Request(command="fault", args=args))


def reply_validator() -> Any:
    """A validator of the API's reply documents, or None while engine/run/cell/schemas has no schema."""
    if not SCHEMA_FILE.is_file():
        return None
    import jsonschema

    defs = json.loads(SCHEMA_FILE.read_text())["$defs"]
    return jsonschema.Draft202012Validator({"$ref": "#/$defs/reply", "$defs": defs})


def wait_for(what: str, check: Any, timeout_s: float = 30.0, every_s: float = 0.05) -> Any:
    """check()'s first true value within *timeout_s* (AssertionError naming *what* otherwise)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s:g} s")
        time.sleep(every_s)
