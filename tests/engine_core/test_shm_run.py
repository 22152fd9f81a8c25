"""A run split over two processes of one host sends its large messages through shared memory.

Over the link of one host (engine.transport.local_link) or, with ``local_links: false``, zenoh.
The producer publishes Blobs of 1.2 MB (bytes: written straight into a shared-memory buffer,
engine.transport.shm.ShmPool.wrap_parts) and point clouds of 1.2 MB (an array: encoded, then put from the
pool, ShmPool.wrap); the consumer writes the SHA-256 of every message it got. What arrives is what
was sent, in order, whether the run records (the encoded bytes also go to the recorder) or not,
and with shared memory off (everything through the socket); the producer's summary counts the
payloads that went through shared memory.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from process_helpers import free_port, start
from stage_fixtures import blob_bytes

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]

N, SIZE, POINTS = 4, 1_200_000, 50_000  # 50 000 points x 3 x 8 bytes = 1.2 MB

RECIPE = """
name: shm_split
plugins: [stage_fixtures]
{zenoh}
processes:
  producer: {{listen: ["tcp/127.0.0.1:{port}"]}}
  consumer: {{connect: ["tcp/127.0.0.1:{port}"], listen: []}}
stages:
  src:  {{type: t_blob_source, process: producer, params: {{n: {n}, size: {size}, points: {points}}}}}
  sink: {{type: t_digest_sink, process: consumer, inputs: {{blob: src.out, cloud: src.cloud}}, params: {{output: "{out}"}}}}
"""


def expected() -> list[list]:
    rows = []
    for i in range(N):
        cloud = (np.arange(3 * POINTS, dtype=float).reshape(-1, 3) + i).tobytes()
        rows.append(["blob", i + 1, SIZE, hashlib.sha256(blob_bytes(i, SIZE)).hexdigest()])
        rows.append(["cloud", i + 1, len(cloud), hashlib.sha256(cloud).hexdigest()])
    return rows


def summary_json(output: str) -> dict:
    """The ``--json`` summary of a ``vgr run``: its stdout's one JSON line."""
    return json.loads(next(line for line in reversed(output.splitlines()) if line.startswith("{")))


@pytest.mark.parametrize(
    ("record", "shared_memory", "links"),
    [(False, True, True), (True, True, True), (False, False, True), (False, True, False)],
    ids=["direct", "recorded", "off", "zenoh"],
)
def test_large_messages_arrive_whole_and_in_order(tmp_path, record, shared_memory, links):
    out = tmp_path / "digests.json"
    recipe = tmp_path / "r.yaml"
    settings = [] if shared_memory else ["shared_memory: false"]
    settings += [] if links else ["local_links: false"]  # (zenoh's shared memory and views, no link)
    zenoh = f"zenoh: {{{', '.join(settings)}}}" if settings else ""
    recipe.write_text(RECIPE.format(zenoh=zenoh, port=free_port(), n=N, size=SIZE, points=POINTS, out=out))
    extra = ["--json"] if record else ["--json", "--no-record"]
    consumer = start(recipe, "consumer", tmp_path, *extra)
    producer = start(recipe, "producer", tmp_path, *extra)
    out_p, _ = producer.communicate(timeout=90)
    out_c, _ = consumer.communicate(timeout=90)
    assert producer.returncode == 0, out_p
    assert consumer.returncode == 0, out_c

    got = json.loads(out.read_text())
    by_port = {port: [r for r in got if r[0] == port] for port in ("blob", "cloud")}
    want = expected()
    assert by_port["blob"] == [r for r in want if r[0] == "blob"]  # every byte, in publication order
    assert by_port["cloud"] == [r for r in want if r[0] == "cloud"]
    counts = summary_json(out_p)["shared_memory"]
    assert counts == ({"payloads": 2 * N, "fallbacks": 0} if shared_memory else {})
