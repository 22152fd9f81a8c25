"""An input fed by another process, seen from the receiving process: a foreign zenoh session plays the
producing process (its liveliness tokens, its publications) so the test controls the exact bytes.

The port's fast path (a DATA envelope of its own type at this schema version), the general path
(an older schema version), batches of messages (engine.transport.wire), a garbled envelope alone or inside a
batch (a warning, nothing else lost) and the end of stream all go through one channel: every
message arrives once, in order, with its seq."""

from __future__ import annotations

import json
import threading
import time

import pytest
import zenoh
from process_helpers import free_port
from recipe_helpers import graph_from
from stage_fixtures import COLLECTED

from engine.messages import Request, codec
from engine.messages.codec import Envelope, Kind
from engine.run.runner import Runner
from engine.transport.bus import active_key, ready_key, started_key, wire_key
from engine.transport.peers import members_digest, peer_key
from engine.transport.wire import BATCH_ENVELOPE, pack_batch

pytestmark = pytest.mark.timeout(60)

RECIPE = """
name: remote_in
plugins: [stage_fixtures]
run_id: {rid}
processes:
  a: {{listen: ["tcp/127.0.0.1:{port}"]}}
  b: {{connect: ["tcp/127.0.0.1:{port}"], listen: []}}
stages:
  src:  {{type: t_counter, process: a, params: {{n: 1}}}}
  sink: {{type: t_collector, process: b, inputs: {{in: src.out}}}}
"""


def test_remote_input_delivers_fast_path_general_path_and_end_of_stream_in_order():
    rid, port = "remote_in_t1", free_port()
    runner = Runner(graph_from(RECIPE.format(rid=rid, port=port)), process="b", ready_timeout_s=20)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    session = zenoh.open(conf)
    try:
        # process a as engine.transport.peers knows a process: its session and epoch, the members it started with
        peer = peer_key(rid, "a", str(session.zid()), "e1")
        started = f"{peer}/started/{members_digest({'a': 'e1', 'b': runner.members.epoch})}"
        tokens = [
            session.liveliness().declare_token(k)
            for k in (peer, started, ready_key(rid, "src"), started_key(rid, "a"), active_key(rid, "a"))
        ]
        pub = session.declare_publisher(wire_key(rid, "src", "out"), congestion_control=zenoh.CongestionControl.BLOCK)
        result: dict[str, object] = {}
        th = threading.Thread(target=lambda: result.update(summary=runner.run()))
        th.start()
        deadline = time.monotonic() + 20
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)

        def record(seq: int, version: int = codec.SCHEMA_VERSION) -> tuple[bytes, bytes]:
            msg = Request(command="c", args={"i": seq}, stamp_ns=1000 + seq)
            env = Envelope(Kind.DATA, seq, msg.stamp_ns, msg.TYPE, schema_version=version)
            return codec.encode_envelope(env), codec.encode_payload(msg)

        def put(seq: int, version: int = codec.SCHEMA_VERSION) -> None:
            env, payload = record(seq, version)
            pub.put(payload, attachment=env)

        for seq in range(1, 31):
            put(seq)
        # a batch (engine.transport.wire) of 31..40 with a garbled record in the middle: only that one is lost
        batch = [record(seq) for seq in range(31, 36)] + [(b"garbage", b"\x00")] + [record(s) for s in range(36, 41)]
        pub.put(pack_batch(batch), attachment=BATCH_ENVELOPE)
        put(41, version=0)  # an older writer's envelope: the general path
        pub.put(b"\x01\x02", attachment=b"not an envelope")  # ignored, with a warning
        # the end of stream inside the last batch
        eos = (codec.encode_envelope(Envelope(Kind.EOS, 61, 0, "")), b"")
        pub.put(pack_batch([record(seq) for seq in range(42, 61)] + [eos]), attachment=BATCH_ENVELOPE)
        rows = COLLECTED[rid]["sink"]
        while len(rows) < 60 and time.monotonic() < deadline:
            time.sleep(0.01)
        tokens.pop().undeclare()  # process a is no longer active: b's run may end
        th.join(20)
        assert not th.is_alive()
    finally:
        session.close()
    summary = result["summary"]
    assert [r["seq"] for r in rows] == list(range(1, 61))
    assert [r["args"]["i"] for r in rows] == list(range(1, 61))
    assert summary.ok, summary.stop_reason  # type: ignore[attr-defined]
    codes = [e.code for e in summary.events]  # type: ignore[attr-defined]
    assert codes.count("undecodable_message") == 2 and "sequence_gap" not in codes
