"""engine.run.process_memory: a vgr run's process keeps the heap memory of large messages it freed.

Checked through glibc's own counters (``mallinfo2``: ``hblks`` is the number of blocks the
allocator took with a fresh ``mmap``) in a fresh interpreter each time, so nothing else this test
process did moves glibc's self-adjusting thresholds first.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from process_helpers import env

pytestmark = pytest.mark.subprocess

PROBE = """
import ctypes, json, sys
libc = ctypes.CDLL(None)
if not hasattr(libc, "mallinfo2"):
    print(json.dumps(None)); sys.exit()
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
libc.mallinfo2.restype = Info
took = None
if sys.argv[1] == "1":
    from engine.run.process_memory import keep_freed_memory
    took = keep_freed_memory()
    assert keep_freed_memory() == took  # once is enough; again changes nothing
before = libc.mallinfo2()
buf = bytearray(8_000_000)  # a large message's buffer
during = libc.mallinfo2()
del buf
after = libc.mallinfo2()
print(json.dumps({"took": took, "mapped": during.hblks - before.hblks, "arena_kept": after.arena >= during.arena}))
"""


def probe(keep: bool) -> dict | None:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, "1" if keep else "0"], env=env(), capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_large_buffers_come_from_the_heap_and_their_memory_stays_for_the_next_message():
    default, kept = probe(False), probe(True)
    if default is None:
        pytest.skip("not glibc (no mallinfo2): keep_freed_memory does nothing there")
    assert default["mapped"] == 1  # glibc's default: a fresh mapping for every large buffer
    assert kept == {"took": True, "mapped": 0, "arena_kept": True}
