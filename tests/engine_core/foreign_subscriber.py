"""A zenoh subscriber that knows nothing of vgr but docs/zenoh_layout.md: zenoh, protobuf, the standard
library. Run as a script (never imported by vgr's tests): it listens on ENDPOINT, waits until a run
answers ``vgr/*/_info/*``, builds the message classes from the descriptors the run published,
decodes N data samples of each wanted topic and prints one JSON line per sample, then a last line
listing the top-level modules it imported.

    python foreign_subscriber.py ENDPOINT N TOPIC [TOPIC ...]
"""

import base64
import json
import queue
import struct
import sys
import time

import zenoh
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

ENVELOPE = struct.Struct("<4sBBHQq")  # magic "VGR" + layout version, kind, schema version, reserved, seq, stamp


def main() -> None:
    endpoint, n, wanted = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    conf = zenoh.Config()
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    print(json.dumps({"ready": True}), flush=True)
    info = None
    deadline = time.monotonic() + 60
    while info is None and time.monotonic() < deadline:
        for reply in session.get("vgr/*/_info/*", timeout=1.0):
            if reply.ok is not None:
                info = json.loads(reply.ok.payload.to_bytes())
        time.sleep(0.05)
    assert info is not None, "no run answered"
    assert info["layout"] == 1
    pool = descriptor_pool.DescriptorPool()
    for encoded in info["schemas"].values():
        for fd in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(encoded)).file:
            try:
                pool.FindFileByName(fd.name)
            except KeyError:
                pool.Add(fd)
    topics = {t["key"]: t for t in info["topics"] if t["topic"] in wanted}
    samples: queue.SimpleQueue = queue.SimpleQueue()
    subs = [session.declare_subscriber(key, samples.put) for key in topics]
    got = {t: 0 for t in wanted}
    while min(got.values()) < n:
        sample = samples.get(timeout=30)
        att = sample.attachment.to_bytes()
        magic, kind, schema_version, _, seq, stamp = ENVELOPE.unpack_from(att)
        assert magic[:3] == b"VGR" and magic[3] == info["layout"], magic
        if kind != 0:  # 0 data, 1 end of stream
            continue
        topic = topics[str(sample.key_expr)]
        type_name = att[ENVELOPE.size :].decode()
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(topic["schema"]))
        msg = cls.FromString(sample.payload.to_bytes())
        out = {
            "topic": topic["topic"],
            "seq": seq,
            "stamp_ns": stamp,
            "type": type_name,
            "schema_version": schema_version,
        }
        if topic["schema"] == "foxglove.PointCloud":
            out["frame_id"] = msg.frame_id
            out["points"] = len(msg.data) // msg.point_stride
            out["first_xyz"] = list(struct.unpack_from("<3f", msg.data, 0))
        elif topic["schema"] == "foxglove.PoseInFrame":
            p = msg.pose.position
            out["frame_id"] = msg.frame_id
            out["position"] = [p.x, p.y, p.z]
        got[topic["topic"]] += 1
        print(json.dumps(out), flush=True)
    for s in subs:
        s.undeclare()
    session.close()
    print(json.dumps({"modules": sorted({m.split(".")[0] for m in sys.modules})}), flush=True)


if __name__ == "__main__":
    main()
