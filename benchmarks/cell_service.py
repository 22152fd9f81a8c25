"""The cell service under a robot program: cycle time, stability over many cycles, memory, recording,
replay, against a fresh ``vgr run`` per part. One run measures:

* **service, camera in-process** (``vgr serve recipes/cell_service_sim.yaml``) and **service, camera
  in its own process** (``-p vars.camera_process=cam``, plus ``vgr serve ... --process cam``): each
  a server of its own (own cell name ``bench_<pid>_<n>``, own ``--runs-dir``), both up for the whole
  run, driven by plugins.sim.cell_controller.SimController (parts at random offsets, seed fixed, the
  same parts for both). Per cycle: the controller-side round trip of ``locate`` (perf_counter, the
  request sent to the reply decoded), the reply's ``timing_ms`` (``total`` and each service the job
  called), its status; p50 / p99 / max of each, and ``overhead`` = round trip - the job's total
  (transport and service) and ``job_overhead`` = total - capture - match. Docking: the controller
  moves by the correction and the truth gives the docking error; a docked cycle costs two real robot
  moves (to the install pose and back to the photo pose), which takes longer than the locate itself
  once the matcher is fast (see below), so only every ``--dock-every``-th cycle docks (default 10;
  the others take the next part at once). The locate round trip does not include the moves (they
  come before and after it), so docking changes no timing figure, only how long the run takes.
* **no cycle lost or answered twice**: every request (its own id) got exactly one reply (zenoh's
  replies counted: consolidation none, every queryable), with its id, status not ``busy``, cycle
  numbers 1..N in order; the run folder's ``cycles.jsonl`` has exactly one line per request, cycle
  numbers distinct and 1..N, the ids those sent.
* **memory and open files**: ``rss_mb`` / ``open_files`` of the service's ``status`` at cycle 100
  and after the last cycle (and after every block, ``series``); for the camera process, which has
  no ``status``, the same read from ``/proc/<pid>``. Growth = last - cycle 100.
* **bytes recorded per cycle**: the recipe keeps 1000 cycle files / 500 MB (``serve.record``), older
  files are removed; so the folder is scanned as the run goes (every 100 cycles and after every
  block) and the size of every finished cycle file is taken then: ``bytes_per_cycle``
  covers every cycle, not only the kept ones.
* **replay**: ``--replays`` of the kept cycle files per configuration (evenly spread over them),
  each replayed with engine.recording.replay.replay (in a child process, so the wait is bounded):
  outcome ok, and identical (every stream and request ``identical``, not only within tolerance).
* **one-shot**: ``vgr run recipes/eye_in_hand_dock.yaml --no-progress --runs-dir <tmp>`` per part,
  a fresh process each (a cell without a service), ``--one-shot-runs`` times, alternated with the
  blocks of service cycles (the two configurations' blocks alternate too, ABBA), so all three see
  the same machine; wall time per run. It runs with the same ``matcher.first_method`` as the service.
  (It does more than one locate: a guided job of three looks, two moves and the docking; it is what
  a cell without a service does per part.)

Targets (PASS/FAIL, in the JSON): service p50 <= one-shot p50 / 5 and service p99 <= 2 x service p50
(the locate round trip, each configuration); RSS growth < 20 MB (each process); no cycle lost or
answered twice; every sampled replay identical.

**The matcher's first look.** The recipe as shipped matches the first look with global registration
(~0.35 s of a ~0.37 s locate on this 2-core machine; with the robot moves, 10,000 cycles per
configuration would take over an hour each). The parts come within +-10 mm / +-5 deg of the template
pose, where fine ICP from identity converges to the same optimum. Measured with 30 cycles each (camera
in-process, docking every cycle, seed 0): global: 30/30 ok, locate p50 373 ms (match_first 347 ms),
docking error median 0.153 mm / 0.0223 deg, p95 0.298 mm / 0.0364 deg, max 0.406 mm / 0.0403 deg;
``matcher.first_method=fine``: 30/30 ok, locate p50 156 ms (match_first 131 ms), the same docking
errors to 1e-12 mm (the error is the believed hand-eye transform's, not the matcher's). This
benchmark measures the service (its overhead, its stability over 10,000 cycles, memory, recording,
replay), not the matcher, whose cost benchmarks/registration.py measures; so it runs
``-p matcher.first_method=fine`` by default, the one-shot runs too (``--first-method global``: the
recipes as shipped). With fine, a docked cycle takes ~0.40 s at the controller, of which the locate
~0.16 s: docking more than doubles a cycle, hence ``--dock-every 10``.

``idle_cpu_cores``: the share of a core each server process uses while it waits (over 3 s, from 2 s
after its last cycle), before the first block and after the last. A waiting server should use
none; more than 5 % is warned about in the results, since the services and the one-shot runs share
the machine with the servers that wait meanwhile.

Usage: ``python benchmarks/cell_service.py [--quick] [--cycles N] [--one-shot-runs M]
[--first-method fine|global]``; writes benchmarks/results/cell_service.json (``--quick``: 200 cycles,
3 one-shot runs, 10 replays, cell_service_quick.json, git-ignored). Everything it writes goes to a
temporary folder, removed at the end (``--keep``: kept).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(HERE), str(ROOT)]

from bench_results import machine  # noqa: E402

RECIPE = ROOT / "recipes" / "cell_service_sim.yaml"
ONE_SHOT_RECIPE = ROOT / "recipes" / "eye_in_hand_dock.yaml"
CONFIGS = ("in_process", "camera_process")
MAX_BLOCK = 500  # cycles of one configuration between two scans of its cycle files (it keeps 1000)
READY_TIMEOUT_S = 120.0
LOCATE_TIMEOUT_S = 60.0
STATUS_TIMEOUT_S = 15.0
STOP_TIMEOUT_S = 30.0
ONE_SHOT_TIMEOUT_S = 300.0
REPLAY_TIMEOUT_S = 60.0  # per file, on top of a minute for the child's start
IDLE_SETTLE_S = 2.0
IDLE_WINDOW_S = 3.0
CYCLE_FILE_RE = re.compile(r"^cycle-(\d{7})\.mcap$")
TARGETS = {"speedup_vs_one_shot": 5.0, "p99_over_p50": 2.0, "rss_growth_mb": 20.0}


def vgr_command() -> list[str]:
    exe = Path(sys.executable).parent / "vgr"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "engine.cli.main"]


def stats(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {"n": 0, "p50": None, "p99": None, "max": None}
    a = np.asarray(values, dtype=float)
    return {
        "n": int(a.size),
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
    }


def error_stats(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {"n": 0, "median": None, "p95": None, "max": None}
    a = np.asarray(values, dtype=float)
    return {"n": int(a.size), "median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())}


def proc_cpu_s(pid: int) -> float | None:
    """CPU seconds (user + system, every thread) process *pid* has used."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_rss_mb(pid: int) -> float | None:
    try:
        pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def proc_open_files(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def serve_has_cell_option() -> bool:
    """``vgr serve --cell NAME`` (a recipe's ``serve:`` block is not reachable with ``-p``)."""
    out = subprocess.run([*vgr_command(), "serve", "--help"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    return "--cell" in out.stdout


# --------------------------------------------------------------------------- servers
class Server:
    """One configuration's service: ``vgr serve`` (and, for camera_process, its camera process)."""

    def __init__(self, config: str, index: int, work: Path, first_method: str, cell_option: bool) -> None:
        self.config = config
        self.cell = f"bench_{os.getpid()}_{index}"
        self.runs_dir = work / config
        self.runs_dir.mkdir(parents=True)
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: dict[str, Path] = {}
        self.params = [f"matcher.first_method={first_method}"]
        if config == "camera_process":
            self.params.append("vars.camera_process=cam")
        self.recipe = RECIPE
        self.naming: list[str] = ["--cell", self.cell]
        if not cell_option:  # this vgr cannot rename a cell: a copy of the recipe under another name
            import yaml

            data = yaml.safe_load(RECIPE.read_text(encoding="utf-8"))
            data["serve"]["cell"] = self.cell
            data["vars"]["template"] = str((RECIPE.parent / data["vars"]["template"]).resolve())
            self.recipe = work / f"{self.cell}.yaml"
            self.recipe.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
            self.naming = []
        self.client: Any = None
        self.run_folder: Path | None = None
        self.main_pid: int | None = None

    def _start(self, process: str) -> None:
        cmd = [*vgr_command(), "serve", str(self.recipe), *self.naming, "--runs-dir", str(self.runs_dir)]
        cmd += ["--ready-timeout", "60"]
        for p in self.params:
            cmd += ["-p", p]
        if process != "main":
            cmd += ["--process", process]
        log = self.logs[process] = self.runs_dir / f"{process}.log"
        with log.open("wb") as f:
            self.procs[process] = subprocess.Popen(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT)

    def start(self) -> None:
        from engine.run.cell.client import CellClient, CellUnreachableError

        self._start("main")
        if self.config == "camera_process":
            self._start("cam")
        deadline = time.monotonic() + READY_TIMEOUT_S
        while True:
            for name, p in self.procs.items():
                if p.poll() is not None:
                    raise RuntimeError(
                        f"{self.config}: vgr serve ({name}) ended with {p.returncode}:\n{self.log_tail(name)}"
                    )
            try:
                client = CellClient(self.cell, timeout_s=LOCATE_TIMEOUT_S, connect_timeout_s=1.0)
            except CellUnreachableError:
                client = None
            if client is not None:
                try:
                    status = client.call("status")
                except CellUnreachableError:
                    status = {}
                if status.get("result", {}).get("ready"):
                    self.client = client
                    self.run_folder = Path(status["result"]["run_folder"])
                    self.main_pid = int(status["result"]["pid"])
                    return
                client.close()
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.config}: cell {self.cell} not ready within {READY_TIMEOUT_S:g} s")
            time.sleep(0.5)

    def status(self) -> dict[str, Any]:
        saved, self.client.timeout_s = self.client.timeout_s, STATUS_TIMEOUT_S
        try:
            return self.client.call("status")["result"]
        finally:
            self.client.timeout_s = saved

    def pids(self) -> dict[str, int]:
        out = {name: p.pid for name, p in self.procs.items()}
        if self.main_pid is not None:
            out["main"] = self.main_pid
        return out

    def log_tail(self, process: str, lines: int = 30) -> str:
        try:
            return "\n".join(self.logs[process].read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def stop(self) -> dict[str, int | None]:
        """SIGINT (the service's orderly stop), a second SIGINT after STOP_TIMEOUT_S, a kill after as long
        again; the camera process first gets STOP_TIMEOUT_S to end with the service's run, unsignalled."""
        if self.client is not None:
            with contextlib.suppress(Exception):  # (the session may be gone already)
                self.client.close()
            self.client = None
        codes: dict[str, int | None] = {}
        for name in ("main", "cam"):  # the service first: its end ends the camera process's run
            p = self.procs.get(name)
            if p is None:
                continue
            if name != "main" and "main" in self.procs:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    p.wait(STOP_TIMEOUT_S)
            for sig, wait in ((signal.SIGINT, STOP_TIMEOUT_S), (signal.SIGINT, STOP_TIMEOUT_S), (signal.SIGKILL, 10.0)):
                if p.poll() is not None:
                    break
                p.send_signal(sig)
                try:
                    p.wait(wait)
                except subprocess.TimeoutExpired:
                    continue
            codes[name] = p.poll()
        from engine.transport.endpoints import private_socket_dir

        with contextlib.suppress(OSError):  # the cell's socket folder, once empty (vgr serve leaves it)
            (private_socket_dir() / self.cell).rmdir()
        return codes


# --------------------------------------------------------------------------- one configuration's cycles
class Measured:
    """The cycles of one configuration: the controller, its timed locate, what it saw."""

    def __init__(self, server: Server, seed: int, dock_every: int) -> None:
        from plugins.sim.cell_controller import SimController

        self.server = server
        self.dock_every = dock_every
        self.controller = SimController(server.client, seed=seed, dock=True)
        self.controller.client.locate = self._locate  # the controller's locate, timed and counted
        self.requests: list[dict[str, Any]] = []
        self.cycles: list[dict[str, Any]] = []
        self.errors: list[str] = []
        self.file_sizes: dict[int, int] = {}  # cycle -> bytes of its finished file
        self.files_seen_at_end: list[Path] = []
        self.status_series: list[dict[str, Any]] = []
        self.status_at: dict[str, dict[str, Any]] = {}
        self.consecutive_failures = 0

    def _locate(self, pose: Any = None, *, count: int = 1, request_id: str | None = None) -> dict[str, Any]:
        from engine.run.cell import protocol
        from engine.run.cell.client import CellUnreachableError, new_id

        client = self.server.client
        rid = request_id or new_id("bench")
        doc: dict[str, Any] = {"api": protocol.API_VERSION, "id": rid, "count": count}
        if pose is not None:
            doc["pose"] = protocol.pose_doc(np.asarray(pose, dtype=float))
        record: dict[str, Any] = {"id": rid, "replies": 0}
        self.requests.append(record)
        t0 = time.perf_counter()
        try:
            answers = client._bus.request(
                protocol.api_key(client.cell, "locate"), protocol.encode(doc), b"", LOCATE_TIMEOUT_S
            )
        except (TimeoutError, LookupError) as exc:
            record["error"] = f"{type(exc).__name__}: {exc}"
            raise CellUnreachableError(record["error"]) from None
        record["rt_ms"] = (time.perf_counter() - t0) * 1e3
        record["replies"] = len(answers)
        good = [a for a in answers if a.error is None]
        if not good:
            record["error"] = "; ".join(str(a.error) for a in answers)
            raise CellUnreachableError(record["error"])
        reply = json.loads(good[0].payload)
        record["reply_id"], record["status"], record["cycle"] = reply.get("id"), reply.get("status"), reply.get("cycle")
        record["timing_ms"] = reply.get("timing_ms", {})
        return reply

    def run(self, n: int) -> None:
        for _ in range(n):
            ctl = self.controller
            ctl.dock = self.dock_every > 0 and ctl.parts % self.dock_every == 0  # (parts: done so far)
            try:
                outcome = ctl.cycle()
            except Exception as exc:  # said in the results; too many in a row end the run
                self.errors.append(f"part {ctl.parts}: {type(exc).__name__}: {exc}")
                self.consecutive_failures += 1
                if self.consecutive_failures >= 10:
                    raise RuntimeError(f"{self.server.config}: 10 failed cycles in a row: {self.errors[-3:]}") from exc
                continue
            self.consecutive_failures = 0
            self.cycles.append(
                {
                    "part": outcome.part,
                    "status": outcome.status,
                    "cycle": outcome.cycle,
                    "docked": ctl.dock,
                    "error_mm": outcome.error_mm,
                    "error_deg": outcome.error_deg,
                }
            )
            done = len(self.requests)
            if done == 100:
                self.status_at["cycle_100"] = self.sample(done)
            if done % 100 == 0:
                self.scan_files()

    def sample(self, done: int) -> dict[str, Any]:
        s = self.server.status()
        point: dict[str, Any] = {
            "requests": done,
            "cycles": s["cycles"],
            "rss_mb": s["rss_mb"],
            "open_files": s["open_files"],
        }
        cam = self.server.procs.get("cam")
        if cam is not None:
            point["cam_rss_mb"], point["cam_open_files"] = proc_rss_mb(cam.pid), proc_open_files(cam.pid)
        point["takt_ms"], point["takt_parts_ms"] = s.get("takt_ms"), s.get("takt_parts_ms")
        self.status_series.append(point)
        return point

    def scan_files(self, final: bool = False) -> None:
        """Sizes of the finished cycle files (all but the newest while the service runs)."""
        folder = self.server.run_folder / "cycles"
        numbered = []
        for p in folder.iterdir():
            m = CYCLE_FILE_RE.match(p.name)
            if m:
                numbered.append((int(m.group(1)), p))
        numbered.sort()
        if not final and numbered:
            numbered = numbered[:-1]
        served = max((r.get("cycle") or 0 for r in self.requests), default=0)
        numbered = [(n, p) for n, p in numbered if n <= served]  # (the file opened after the last cycle: empty)
        for number, p in numbered:
            with contextlib.suppress(OSError):  # (removed by the retention meanwhile)
                self.file_sizes[number] = p.stat().st_size
        if final:
            self.files_seen_at_end = [p for _, p in numbered]


def no_loss_check(m: Measured) -> dict[str, Any]:
    """Every request answered exactly once, in order; cycles.jsonl one line per request."""
    reqs = m.requests
    n = len(reqs)
    problems: list[str] = []
    replies = [r.get("replies", 0) for r in reqs]
    if any(k != 1 for k in replies):
        problems.append(
            f"{sum(k == 0 for k in replies)} request(s) without a reply, {sum(k > 1 for k in replies)} with more than one"
        )
    wrong_id = [r["id"] for r in reqs if r.get("reply_id") not in (None, r["id"])]
    if wrong_id:
        problems.append(f"{len(wrong_id)} reply(ies) with another request's id (first {wrong_id[0]})")
    cycles = [r.get("cycle") for r in reqs]
    if cycles != list(range(1, n + 1)):
        problems.append(
            f"reply cycle numbers are not 1..{n} in order (first bad at request {next((i + 1 for i, c in enumerate(cycles) if c != i + 1), None)})"
        )
    busy = sum(r.get("status") == "busy" for r in reqs)
    if busy:
        problems.append(f"{busy} request(s) answered busy")
    lines = []
    log_path = m.server.run_folder / "cycles.jsonl"
    for raw in log_path.read_text(encoding="utf-8").splitlines():
        if raw.strip():
            lines.append(json.loads(raw))
    log_cycles = [int(x["cycle"]) for x in lines]
    log_ids = [x["id"] for x in lines]
    if len(lines) != n:
        problems.append(f"cycles.jsonl has {len(lines)} line(s) for {n} request(s)")
    if sorted(log_cycles) != list(range(1, len(lines) + 1)) or len(set(log_cycles)) != len(log_cycles):
        problems.append("cycles.jsonl cycle numbers are not distinct 1..N")
    if sorted(log_ids) != sorted(r["id"] for r in reqs):
        problems.append("cycles.jsonl ids are not the ids sent, one each")
    return {
        "requests": n,
        "replies": int(sum(replies)),
        "cycles_jsonl_lines": len(lines),
        "controller_errors": m.errors,
        "problems": problems,
        "ok": not problems and not m.errors,
    }


# --------------------------------------------------------------------------- one-shot and replay
def one_shot(work: Path, first_method: str) -> dict[str, Any]:
    runs = work / "one_shot"
    runs.mkdir(exist_ok=True)
    cmd = [*vgr_command(), "run", str(ONE_SHOT_RECIPE), "--no-progress", "--runs-dir", str(runs)]
    cmd += ["-p", f"matcher.first_method={first_method}"]
    t0 = time.perf_counter()
    try:
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=ONE_SHOT_TIMEOUT_S)
        wall, rc, tail = time.perf_counter() - t0, done.returncode, done.stdout[-400:] + done.stderr[-400:]
    except subprocess.TimeoutExpired:
        wall, rc, tail = time.perf_counter() - t0, None, "timed out"
    m = re.search(r"docking error ([\d.]+) mm / ([\d.]+) deg", tail)
    for folder in runs.iterdir():  # (a few MB each: not kept)
        shutil.rmtree(folder, ignore_errors=True)
    return {
        "wall_s": wall,
        "rc": rc,
        "error_mm": float(m.group(1)) if m else None,
        "error_deg": float(m.group(2)) if m else None,
        **({"tail": tail} if rc != 0 else {}),
    }


def replay_worker(files_json: str, out_json: str) -> None:
    """Child process: replay each file, write one result per file."""
    from engine.recording.diff import IDENTICAL
    from engine.recording.replay import replay

    results = []
    for path in json.loads(Path(files_json).read_text()):
        t0 = time.perf_counter()
        try:
            report, _, _ = replay(path)
            verdicts = [v.verdict for v in (*report.streams, *report.requests)]
            results.append(
                {
                    "file": Path(path).name,
                    "outcome": report.outcome,
                    "identical": report.outcome == "ok" and all(v == IDENTICAL for v in verdicts),
                    "verdicts": {v: verdicts.count(v) for v in set(verdicts)},
                    "failures": report.failures,
                    "wall_s": time.perf_counter() - t0,
                }
            )
        except Exception as exc:  # a replay that cannot run is a failed replay
            results.append(
                {
                    "file": Path(path).name,
                    "outcome": "error",
                    "identical": False,
                    "error": f"{type(exc).__name__}: {exc}",
                }
            )
        Path(out_json).write_text(json.dumps(results))


def replays(m: Measured, count: int, work: Path) -> dict[str, Any]:
    files = m.files_seen_at_end
    if count <= 0 or not files:
        return {"sampled": 0, "kept_files": len(files), "identical": 0, "ok": 0, "results": []}
    idx = sorted({round(float(i)) for i in np.linspace(0, len(files) - 1, min(count, len(files)))})
    chosen = [str(files[i]) for i in idx]
    files_json, out_json = work / f"replay_{m.server.config}.json", work / f"replayed_{m.server.config}.json"
    files_json.write_text(json.dumps(chosen))
    timeout = 60.0 + REPLAY_TIMEOUT_S * len(chosen)
    worker = [sys.executable, __file__, "--replay-worker", str(files_json), str(out_json)]
    with contextlib.suppress(subprocess.TimeoutExpired):  # (the files replayed by then are counted)
        subprocess.run(worker, cwd=ROOT, timeout=timeout, check=False)
    results = json.loads(out_json.read_text()) if out_json.exists() else []
    return {
        "sampled": len(chosen),
        "kept_files": len(files),
        "replayed": len(results),
        "ok": sum(r["outcome"] == "ok" for r in results),
        "identical": sum(bool(r["identical"]) for r in results),
        "wall_s": stats([r["wall_s"] for r in results if "wall_s" in r]),
        "not_identical": [r for r in results if not r["identical"]],
    }


# --------------------------------------------------------------------------- summary
def idle_cpu(servers: list[Server]) -> dict[str, dict[str, float | None]]:
    """Share of a core each server process uses while no cycle runs: over IDLE_WINDOW_S, from
    IDLE_SETTLE_S after the last cycle (a recorder flushes after a second)."""
    time.sleep(IDLE_SETTLE_S)
    before = {(s.config, name): proc_cpu_s(pid) for s in servers for name, pid in s.pids().items()}
    time.sleep(IDLE_WINDOW_S)
    out: dict[str, dict[str, float | None]] = {}
    for s in servers:
        for name, pid in s.pids().items():
            a, b = before[(s.config, name)], proc_cpu_s(pid)
            out.setdefault(s.config, {})[name] = None if a is None or b is None else (b - a) / IDLE_WINDOW_S
    return out


def summarize(m: Measured) -> dict[str, Any]:
    reqs = [r for r in m.requests if "rt_ms" in r]
    t = [r["timing_ms"] for r in reqs]
    rt = [r["rt_ms"] for r in reqs]
    total = [x.get("total", math.nan) for x in t]
    cap = [x.get("camera.capture", 0.0) for x in t]
    match = [x.get("matcher.match_first", 0.0) for x in t]
    by_status: dict[str, int] = {}
    for r in m.requests:
        key = r.get("status") or "no reply"
        by_status[key] = by_status.get(key, 0) + 1
    docked = [c for c in m.cycles if c["error_mm"] is not None]
    sizes = list(m.file_sizes.values())
    first, last = m.status_at.get("cycle_100"), m.status_at.get("last")
    memory: dict[str, Any] = {"at_cycle_100": first, "at_last": last}
    if first and last:
        memory["rss_growth_mb"] = last["rss_mb"] - first["rss_mb"]
        memory["open_files_growth"] = last["open_files"] - first["open_files"]
        if "cam_rss_mb" in last and first.get("cam_rss_mb") is not None and last.get("cam_rss_mb") is not None:
            memory["cam_rss_growth_mb"] = last["cam_rss_mb"] - first["cam_rss_mb"]
            memory["cam_open_files_growth"] = last["cam_open_files"] - first["cam_open_files"]
    return {
        "cell": m.server.cell,
        "cycles": len(m.requests),
        "by_status": by_status,
        "locate_round_trip_ms": stats(rt),
        "timing_ms": {
            "total": stats(total),
            "camera.capture": stats(cap),
            "matcher.match_first": stats(match),
            "overhead_round_trip_minus_total": stats([a - b for a, b in zip(rt, total, strict=True)]),
            "job_overhead_total_minus_capture_match": stats(
                [a - b - c for a, b, c in zip(total, cap, match, strict=True)]
            ),
        },
        "docking": {
            "every": m.dock_every,
            "docked": len(docked),
            "error_mm": error_stats([c["error_mm"] for c in docked]),
            "error_deg": error_stats([c["error_deg"] for c in docked]),
        },
        "memory": memory,
        "status_series": m.status_series,
        "bytes_per_cycle": {
            "measured": "every finished cycle file, sized while the service ran (scans at most 100 cycles apart; the retention keeps 1000)",
            "files_sized": len(sizes),
            "mean": float(np.mean(sizes)) if sizes else None,
            "max": int(max(sizes)) if sizes else None,
            "min": int(min(sizes)) if sizes else None,
            "kept_at_end": len(m.files_seen_at_end),
        },
    }


def schedule(n_cycles: int, n_one_shot: int) -> list[tuple[int, bool]]:
    """Blocks: (cycles per configuration, a one-shot run after it), one-shot runs spread evenly."""
    n_blocks = max(n_one_shot, math.ceil(n_cycles / MAX_BLOCK), 1)
    sizes = [n_cycles * (b + 1) // n_blocks - n_cycles * b // n_blocks for b in range(n_blocks)]
    shots = [n_one_shot * (b + 1) // n_blocks > n_one_shot * b // n_blocks for b in range(n_blocks)]
    return list(zip(sizes, shots, strict=True))


def deviations(args: argparse.Namespace) -> list[str]:
    out = []
    if args.first_method != "global":
        out.append(
            "matcher.first_method=fine (the recipe ships global), in the services and the one-shot runs: the benchmark "
            "measures the service, not the matcher (benchmarks/registration.py); see the docstring's 30-cycle comparison"
        )
    if args.dock_every != 1:
        out.append(f"docking every {args.dock_every}th cycle, not every cycle (a docked cycle is two real robot moves)")
    if args.cycles != 10_000:
        out.append(f"{args.cycles} cycles per configuration, not 10,000")
    return out


def verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="200 cycles, 3 one-shot runs, 10 replays, *_quick.json")
    ap.add_argument("--cycles", type=int, default=10_000, help="cycles per configuration")
    ap.add_argument("--one-shot-runs", type=int, default=20)
    ap.add_argument("--replays", type=int, default=100, help="cycle files replayed per configuration")
    ap.add_argument(
        "--first-method", choices=("fine", "global"), default="fine", help="matcher.first_method (see the docstring)"
    )
    ap.add_argument("--dock-every", type=int, default=10, help="dock every k-th cycle (1: every cycle)")
    ap.add_argument("--configs", default=",".join(CONFIGS), help="which configurations (comma-separated)")
    ap.add_argument("--seed", type=int, default=0, help="the controller's part offsets")
    ap.add_argument("--out", type=Path, help="result file (default benchmarks/results/cell_service[_quick].json)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder (run folders, recordings)")
    ap.add_argument("--replay-worker", nargs=2, metavar=("FILES", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.replay_worker:
        replay_worker(*args.replay_worker)
        return 0
    if args.quick:
        args.cycles, args.one_shot_runs, args.replays = 200, 3, 10
    configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    if not configs or any(c not in CONFIGS for c in configs):
        ap.error(f"--configs: of {', '.join(CONFIGS)}")
    out_path = args.out or HERE / "results" / ("cell_service_quick.json" if args.quick else "cell_service.json")

    import engine

    started = time.time()
    work = Path(tempfile.mkdtemp(prefix="vgr-bench-cell-"))
    cell_option = serve_has_cell_option()
    servers = [Server(c, i, work, args.first_method, cell_option) for i, c in enumerate(configs)]
    measured: dict[str, Measured] = {}
    one_shots: list[dict[str, Any]] = []
    exit_codes: dict[str, Any] = {}
    idle: dict[str, Any] = {}
    plan = schedule(args.cycles, args.one_shot_runs)
    try:
        for s in servers:
            s.start()
            print(f"{s.config}: cell {s.cell} ready (run folder {s.run_folder})", flush=True)
        measured = {s.config: Measured(s, args.seed, args.dock_every) for s in servers}
        idle["before"] = idle_cpu(servers)
        for b, (size, shot) in enumerate(plan):
            order = configs if b % 2 == 0 else configs[::-1]  # ABBA: drift hits both alike
            for c in order:
                m = measured[c]
                t0 = time.perf_counter()
                m.run(size)
                m.sample(len(m.requests))
                m.scan_files()
                rt = [r["rt_ms"] for r in m.requests[-size:] if "rt_ms" in r]
                print(
                    f"block {b + 1}/{len(plan)} {c}: {size} cycles in {time.perf_counter() - t0:.1f} s, "
                    f"locate p50 {np.median(rt) if rt else float('nan'):.1f} ms",
                    flush=True,
                )
            if shot:
                one_shots.append(one_shot(work, args.first_method))
                print(
                    f"one-shot {len(one_shots)}/{args.one_shot_runs}: {one_shots[-1]['wall_s']:.2f} s (rc {one_shots[-1]['rc']})",
                    flush=True,
                )
        for m in measured.values():
            m.status_at["last"] = m.status_series[-1] if m.status_series else m.sample(len(m.requests))
        idle["after"] = idle_cpu(servers)
    finally:
        for s in servers:
            exit_codes[s.config] = s.stop()
    for m in measured.values():
        m.scan_files(final=True)

    results: dict[str, Any] = {
        "machine": {
            **machine(),
            "cpu_model": cpu_model(),
            "cores": os.cpu_count(),
            "vgr": engine.__version__,
            "loadavg_at_end": os.getloadavg(),
        },
        "quick": args.quick,
        "parameters": {
            "cycles_per_configuration": args.cycles,
            "one_shot_runs": args.one_shot_runs,
            "replays_per_configuration": args.replays,
            "first_method": args.first_method,
            "dock_every": args.dock_every,
            "seed": args.seed,
            "configurations": configs,
            "blocks": [size for size, _ in plan],
            "recipe": str(RECIPE.relative_to(ROOT)),
            "one_shot_recipe": str(ONE_SHOT_RECIPE.relative_to(ROOT)),
            "overrides": servers[0].params[:1],
            "cell_named_by": "--cell" if cell_option else "a copy of the recipe (vgr serve has no --cell)",
        },
        "deviations": deviations(args),
        "server_exit_codes": exit_codes,
        "idle_cpu_cores": idle,
    }
    for c, m in measured.items():
        row = summarize(m)
        row["no_loss"] = no_loss_check(m)
        row["replay"] = replays(m, args.replays, work)
        results[c] = row
    walls = [r["wall_s"] for r in one_shots if r["rc"] == 0]
    results["one_shot"] = {
        "runs": len(one_shots),
        "failed": sum(r["rc"] != 0 for r in one_shots),
        "wall_s": stats(walls),
        "error_mm": error_stats([r["error_mm"] for r in one_shots if r["error_mm"] is not None]),
        "runs_detail": one_shots,
    }

    targets: dict[str, Any] = {}
    one_p50 = results["one_shot"]["wall_s"]["p50"]
    for c in measured:
        row = results[c]
        p50, p99 = row["locate_round_trip_ms"]["p50"], row["locate_round_trip_ms"]["p99"]
        mem = row["memory"]
        growth = [g for g in (mem.get("rss_growth_mb"), mem.get("cam_rss_growth_mb")) if g is not None]
        rep = row["replay"]
        targets[c] = {
            "service_p50_le_one_shot_p50_over_5": {
                "ok": bool(
                    one_p50 is not None and p50 is not None and p50 <= one_p50 * 1e3 / TARGETS["speedup_vs_one_shot"]
                ),
                "service_p50_ms": p50,
                "one_shot_p50_ms": None if one_p50 is None else one_p50 * 1e3,
                "ratio": None if not (one_p50 and p50) else one_p50 * 1e3 / p50,
            },
            "service_p99_le_2x_p50": {
                "ok": bool(p50 and p99 is not None and p99 <= TARGETS["p99_over_p50"] * p50),
                "p99_over_p50": p99 / p50 if p50 else None,
            },
            "rss_growth_lt_20_mb": {"ok": bool(growth) and max(growth) < TARGETS["rss_growth_mb"], "growth_mb": growth},
            "no_cycle_lost_or_answered_twice": {"ok": row["no_loss"]["ok"], "problems": row["no_loss"]["problems"]},
            "replays_identical": {
                "ok": rep["sampled"] > 0 and rep["identical"] == rep["sampled"],
                "identical": rep["identical"],
                "sampled": rep["sampled"],
            },
        }
    results["targets"] = targets
    idle_max = max((v or 0.0 for when in idle.values() for cfg in when.values() for v in cfg.values()), default=0.0)
    if idle_max > 0.05:
        results["warning"] = (
            f"a server waiting between cycles used up to {idle_max:.2f} of a core: its figures and the others' "
            "are taken on a machine it keeps busy (see idle_cpu_cores)"
        )
    results["wall_s"] = time.time() - started
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(results, indent=1))

    print_summary(results, measured)
    print(
        f"wrote {out_path.relative_to(ROOT) if out_path.is_relative_to(ROOT) else out_path} ({results['wall_s']:.0f} s)"
    )
    if args.keep:
        print(f"kept {work}")
    else:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def print_summary(results: dict[str, Any], measured: dict[str, Measured]) -> None:
    def f(x: Any, fmt: str = ".1f") -> str:
        return "-" if x is None else format(x, fmt)

    for c in measured:
        r = results[c]
        rt, t = r["locate_round_trip_ms"], r["timing_ms"]
        d, mem, b, rep = r["docking"], r["memory"], r["bytes_per_cycle"], r["replay"]
        print(f"\n== {c} ({r['cycles']} cycles, {r['by_status']})")
        print(f"  locate round trip ms  p50 {f(rt['p50'])}  p99 {f(rt['p99'])}  max {f(rt['max'])}")
        for k, v in t.items():
            print(f"  {k:42s} p50 {f(v['p50'])}  p99 {f(v['p99'])}  max {f(v['max'])}")
        print(
            f"  docking ({d['docked']} docked, every {d['every']}): mm median {f(d['error_mm']['median'], '.3f')} "
            f"p95 {f(d['error_mm']['p95'], '.3f')} max {f(d['error_mm']['max'], '.3f')}; deg median "
            f"{f(d['error_deg']['median'], '.4f')} p95 {f(d['error_deg']['p95'], '.4f')} max {f(d['error_deg']['max'], '.4f')}"
        )
        a, z = mem.get("at_cycle_100") or {}, mem.get("at_last") or {}
        print(
            f"  rss MB {f(a.get('rss_mb'))} -> {f(z.get('rss_mb'))} (growth {f(mem.get('rss_growth_mb'))}); open files "
            f"{a.get('open_files')} -> {z.get('open_files')}"
            + (
                f"; camera process {f(a.get('cam_rss_mb'))} -> {f(z.get('cam_rss_mb'))} MB, files {a.get('cam_open_files')} -> {z.get('cam_open_files')}"
                if "cam_rss_mb" in z
                else ""
            )
        )
        print(
            f"  bytes per cycle: mean {f(b['mean'], '.0f')} max {b['max']} ({b['files_sized']} files sized, {b['kept_at_end']} kept)"
        )
        print(
            f"  no loss: {r['no_loss']['requests']} requests, {r['no_loss']['replies']} replies, "
            f"{r['no_loss']['cycles_jsonl_lines']} log lines; problems {r['no_loss']['problems'] or 'none'}"
        )
        print(f"  replay: {rep['identical']}/{rep['sampled']} identical ({rep.get('ok', 0)} ok)")
    o = results["one_shot"]
    print(
        f"\n== one-shot: {o['runs']} runs ({o['failed']} failed), wall s p50 {f(o['wall_s']['p50'], '.2f')} p99 {f(o['wall_s']['p99'], '.2f')}"
    )
    print(f"idle CPU (cores): {results['idle_cpu_cores']}")
    if "warning" in results:
        print(f"WARNING: {results['warning']}")
    print("\ntargets:")
    for c, ts in results["targets"].items():
        for name, v in ts.items():
            detail = {k: val for k, val in v.items() if k != "ok"}
            print(f"  {verdict(v['ok'])}  {c}: {name} {detail}")


if __name__ == "__main__":
    sys.exit(main())
