"""Child process of test_shm.py: a vgr Bus and a WireSender that put payloads of given sizes.

``python shm_child.py ENDPOINT KEY SHM(0|1) SIZE...``: connects to ENDPOINT, waits until the
parent's subscriber matches, sends one payload per SIZE (byte i of payload k is ``(i * 7 + k) % 251``)
through engine.transport.wire.WireSender with the bus's shared-memory pool, prints the pool's counters as
JSON and closes.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from engine.recipe.model import ZenohSettings
from engine.transport.bus import Bus
from engine.transport.wire import WireSender


def payload(k: int, size: int) -> bytes:
    return ((np.arange(size, dtype=np.int64) * 7 + k) % 251).astype(np.uint8).tobytes()


def main(endpoint: str, key: str, shm: bool, sizes: list[int]) -> None:
    bus = Bus(ZenohSettings(listen=[], connect=[endpoint], shared_memory=shm))
    pub = bus.remote_publisher(key)
    deadline = time.monotonic() + 30
    while not pub.matching_status.matching and time.monotonic() < deadline:
        time.sleep(0.01)
    sender = WireSender(pub, "child.out", bus.shm)
    for k, size in enumerate(sizes):
        time.sleep(0.001)  # paced: each is put at once by this thread
        sender.send(payload(k, size), b"env%d" % k)
    sender.close()
    pool = bus.shm
    print(json.dumps({"shared": pool.shared if pool else 0, "fallbacks": pool.fallbacks if pool else 0}), flush=True)
    time.sleep(0.5)  # the parent has taken every sample before the session goes
    bus.close()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3] == "1", [int(x) for x in sys.argv[4:]])
