"""Child process of test_shm_views_processes.py: one end of a stream of views, to be killed.

``python view_child.py send ENDPOINT RUN`` connects, and, once the parent's process ``b`` says it
maps this host's memory, sends payload *k* (:func:`payload`, seq *k*) every 2 ms through
engine.transport.wire.WireSender with a pool of views (engine.transport.shm_views), for ever: the parent
kills it mid-stream. ``python view_child.py hold ENDPOINT RUN N`` says, as process ``b``, that it
maps this host's memory, receives N views of the parent's stream and holds them all (it never lets
one go), prints ``held N`` and waits to be killed.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from engine.messages.codec import Envelope, Kind, encode_envelope
from engine.recipe.model import ZenohSettings
from engine.transport.bus import Bus
from engine.transport.shm_views import ViewPool, ViewReader, consumer_order
from engine.transport.wire import WireSender

SIZE = 1_200_000
KEY = "vgr/{run}/_wire/src/cloud"
CONSUMERS = consumer_order([("b", "sink", "cloud")])


def payload(k: int, size: int = SIZE) -> bytes:
    body = ((np.arange(size, dtype=np.int64) * 7 + k) % 251).astype(np.uint8)
    body[:8] = np.frombuffer(k.to_bytes(8, "little"), np.uint8)
    return body.tobytes()


def send(endpoint: str, run: str) -> None:
    bus = Bus(ZenohSettings(listen=[], connect=[endpoint]))
    peers = bus.host_peers(run, "a")
    pool = ViewPool(peers, CONSUMERS)
    pub = bus.remote_publisher(KEY.format(run=run))
    deadline = time.monotonic() + 30
    while not (pub.matching_status.matching and peers.zids("b")) and time.monotonic() < deadline:
        time.sleep(0.01)
    sender = WireSender(pub, "src.cloud", bus.shm, pool)
    print("sending", flush=True)
    for k in range(1, 100_000):  # (killed long before the end)
        sender.send(payload(k), encode_envelope(Envelope(Kind.DATA, k, k, "Blob")))
        time.sleep(0.002)


def hold(endpoint: str, run: str, n: int) -> None:
    bus = Bus(ZenohSettings(listen=[], connect=[endpoint]))
    _, channel = bus.subscribe_remote(KEY.format(run=run))
    bus.host_peers(run, "b")  # this process maps this host's memory
    reader = ViewReader(0)
    held = []
    deadline = time.monotonic() + 60
    while len(held) < n and time.monotonic() < deadline:
        sample = channel.try_recv()
        if sample is None:
            time.sleep(0.002)
            continue
        if sample.attachment.to_bytes()[4] == Kind.VIEW:
            held.append(reader.payload(sample.payload.to_bytes()))
    print(f"held {len(held)}", flush=True)
    time.sleep(120)


if __name__ == "__main__":
    if sys.argv[1] == "send":
        send(sys.argv[2], sys.argv[3])
    else:
        hold(sys.argv[2], sys.argv[3], int(sys.argv[4]))
