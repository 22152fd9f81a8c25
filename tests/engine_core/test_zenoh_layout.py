"""docs/zenoh_layout.md is enough to read a run: a subscriber in its own process that imports zenoh and
protobuf only (tests/engine_core/foreign_subscriber.py) finds a live run, decodes its point clouds and
poses with the schemas the run published, and gets what the run recorded."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from process_helpers import demo_streaming, env, free_port, vgr

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]


TOPICS = ("/move/cloud", "/move/transform")


def test_foreign_subscriber_decodes_a_run_with_the_published_schemas_alone(tmp_path):
    from engine.messages import codec
    from engine.recording.reader import load

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    clean = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # vgr is not on its path
    sub = subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("foreign_subscriber.py")), endpoint, "4", *TOPICS],
        cwd=tmp_path,
        env=clean,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert sub.stdout is not None
    assert json.loads(sub.stdout.readline()) == {"ready": True}
    record, runs = tmp_path / "run.mcap", tmp_path / "runs"
    run = subprocess.run(
        vgr(*demo_streaming(20, 80, 500), "--connect", endpoint, "--record", str(record), "--runs-dir", str(runs)),
        env=env(),
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in sub.communicate(timeout=30)[0].splitlines()]
    assert sub.returncode == 0
    modules = lines.pop()["modules"]
    assert "engine" not in modules and "plugins" not in modules and "zenoh" in modules
    decoded = {(d["topic"], d["seq"]): d for d in lines}
    assert sum(t == "/move/cloud" for t, _ in decoded) >= 4 and sum(t == "/move/transform" for t, _ in decoded) >= 4

    recorded = {(m.topic, m.seq): m for m in load(record).messages()}
    for key, d in decoded.items():
        m = recorded[key]  # every sample seen live was recorded under the same topic and seq
        assert (d["type"], d["stamp_ns"], d["schema_version"]) == (m.type_name, m.publish_time, 1)
        msg = codec.decode_payload(codec.registry.get(m.type_name), m.payload)
        if d["type"] == "PointCloud":
            assert d["points"] == len(msg.points) == 500 and d["frame_id"] == msg.frame_id == "world"
            np.testing.assert_array_equal(np.float32(d["first_xyz"]), msg.points[0])
        else:
            np.testing.assert_allclose(d["position"], msg.T[:3, 3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(d["position"], [0.010, -0.005, 0.500], atol=1e-12)
