"""Record the golden cycle file CI replays (``make golden``): serve recipes/cell_service_sim.yaml,
answer two ``locate`` requests (the second one's file is the golden: a file that begins mid-run,
whose sequence numbers go on from the first cycle's), stop the service, copy the file.

    python tests/cell/golden_cycle.py recordings/cell_service_cycle.mcap
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main(out: str) -> int:
    from engine.run.cell.client import CellClient, CellUnreachableError

    target = Path(out)
    if target.exists():
        print(f"{target} exists: remove it first (vgr never replaces a file)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="vgr-golden-") as runs:
        cell = f"golden{int(time.time())}"
        argv = [sys.executable, "-m", "engine.cli.main", "serve", "recipes/cell_service_sim.yaml", "--cell", cell]
        server = subprocess.Popen([*argv, "--runs-dir", runs], cwd=ROOT)
        try:
            deadline = time.monotonic() + 120
            while True:
                try:
                    client = CellClient(cell, connect_timeout_s=2.0)
                    break
                except CellUnreachableError:
                    if time.monotonic() > deadline or server.poll() is not None:
                        raise
                    time.sleep(0.5)
            with client:
                for k in (1, 2):
                    reply = client.locate(request_id=f"golden-{k}")
                    assert reply["status"] == "ok", reply
        finally:
            server.send_signal(signal.SIGINT)
            code = server.wait(60)
        files = sorted(Path(runs).glob("*/cycles/cycle-0000002.mcap"))
        if code != 0 or len(files) != 1:
            print(f"the service ended {code}; cycle files: {files}", file=sys.stderr)
            return 1
        shutil.copyfile(files[0], target)
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
