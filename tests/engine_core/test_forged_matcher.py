"""The issue's attack on a dock: a session outside the run answers the matcher's services with its
own result. The run reaches that session (the recipe connects to an endpoint the intruder holds, the
kind of mistake a plain ``tcp/`` endpoint allows); the engine must take no match from it, raise the
alarm, and the robot must make no correction move."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
import zenoh
from process_helpers import ROOT, free_port, run_vgr

from engine.messages import codec
from engine.recording.reader import load
from engine.transforms import T_from_rotvec
from plugins.registration.messages import MatchResult

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(300)]


def test_a_forged_matcher_is_refused_with_an_alarm_and_the_robot_makes_no_correction(tmp_path):
    port = free_port()
    data = yaml.safe_load((ROOT / "recipes/eye_in_hand_dock.yaml").read_text())
    data["stages"]["matcher"]["params"]["template"] = str(ROOT / "recipes/templates/eye_in_hand.vgrtpl")
    data["zenoh"] = {"connect": [f"tcp/127.0.0.1:{port}"]}
    recipe = tmp_path / "dock.yaml"
    recipe.write_text(yaml.safe_dump(data, sort_keys=False))
    run = data["name"]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    asked: list[str] = []
    with zenoh.open(conf) as intruder:
        # the forged matcher: a well-formed, confident match 33 mm and 6 degrees off (the issue's
        # attack made guidance "converge" there), answered at once, before the real matcher can
        forged = MatchResult(frame_id="camera", method="fine", verdict="ok", fitness=1.0, inlier_rmse_m=1e-5)
        forged.T_match = T_from_rotvec([0.0, 0.0, np.radians(6.0)], [0.033, 0.0, 0.0])
        payload, envelope = codec.encode(forged)

        def forge(query: zenoh.Query) -> None:
            asked.append(str(query.key_expr))
            query.reply(query.key_expr, payload, attachment=envelope)

        queryables = [
            intruder.declare_queryable(f"vgr/{run}/matcher/srv/{svc}", forge) for svc in ("match", "match_first")
        ]
        done = run_vgr("run", str(recipe), "--no-progress", cwd=tmp_path, timeout=240)
        for q in queryables:
            q.undeclare()
    out = done.stdout + done.stderr
    assert asked, "the forged matcher was never asked: the test did not test anything"
    assert done.returncode == 1, out  # refused
    assert "forged_reply" in out
    assert "docking error" not in out  # no dock
    rec = load(next(tmp_path.glob("runs/*/*.mcap")))
    corrections = [
        codec.decode_payload(codec.registry.get(m.type_name), m.payload) for m in rec.messages("/docking/correction")
    ]
    assert corrections and all(c.verdict != "ok" for c in corrections), [c.verdict for c in corrections]
    poses = [
        codec.decode_payload(codec.registry.get(m.type_name), m.payload).T for m in rec.messages("/robot/tcp_pose")
    ]
    photo = np.array(data["vars"]["photo_pose"]["matrix"])
    assert np.allclose(poses[-1][:3, 3], photo[:3, 3], atol=1e-4)  # it went to the photo pose and no further
