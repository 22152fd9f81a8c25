"""What vgr reads from outside (recordings, wire messages, endpoints, run ids, replay requests) is
refused with a clear error when it is bad, and replay never drives a device."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from engine.cli.main import main
from engine.messages import PoseStamped
from engine.messages.codec import CodecError, decode_payload
from engine.recipe.endpoint_syntax import endpoint_problem
from engine.recording.reader import RecordingError, load
from engine.recording.replay import ReplayError, replay

DEMO = Path("recordings/demo.mcap")
DOCK = Path("recordings/eye_in_hand_dock.mcap")


def test_a_zero_or_non_unit_quaternion_is_refused_not_taken_for_the_identity():
    for q in ((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0), (0.1, 0.0, 0.0, 0.5)):
        pb = PoseStamped.proto()
        pb.frame_id = "base"
        pb.pose.position.x = 0.1
        o = pb.pose.orientation
        o.x, o.y, o.z, o.w = q
        with pytest.raises(CodecError, match="not a rotation"):
            decode_payload(PoseStamped, pb.SerializeToString())
    o.x, o.y, o.z, o.w = (0.0, 0.0, 0.0, 1.0 + 1e-7)  # a float32 sender's unit quaternion
    assert decode_payload(PoseStamped, pb.SerializeToString()).T[0, 3] == 0.1


def test_replay_refuses_to_rerun_a_device_stage():
    with pytest.raises(ReplayError, match="never connects to or commands a device"):
        replay(DOCK, stages=["robot"])
    with pytest.raises(ReplayError, match="never connects"):
        replay(DOCK, stages=["camera", "guidance"])


def test_replay_cli_refuses_a_device_stage_with_exit_2(tmp_path, capsys):
    assert main(["replay", str(DOCK), "--stages", "robot", "--runs-dir", str(tmp_path)]) == 2
    assert "never connects" in capsys.readouterr().err.replace("\n", " ")
    assert not list(tmp_path.iterdir())  # and leaves no folder behind


@pytest.mark.parametrize("run_id", ["**", "a/b", "run*", "$x", "1run"])
def test_a_run_id_with_key_wildcards_is_refused_before_anything_starts(tmp_path, run_id):
    argv = ["run", "recipes/demo.yaml", "--run-id", run_id, "--runs-dir", str(tmp_path / "runs"), "--no-progress"]
    assert main(argv) == 2
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("seed", [20, 37, 38, 1, 5])  # 20, 37, 38 broke zstd and the MCAP reader itself
def test_a_bit_flipped_recording_is_refused_or_replayed_never_a_traceback(tmp_path, seed):
    r = random.Random(seed)
    data = bytearray(DEMO.read_bytes())
    for _ in range(r.choice([1, 3, 10])):
        data[r.randrange(len(data))] ^= 1 << r.randrange(8)
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    try:
        load(damaged)
    except RecordingError as exc:
        said = str(exc)
        assert "is damaged" in said or "cannot read" in said or "not a vgr recording" in said or "no summary" in said
    code = main(["replay", str(damaged), "--runs-dir", str(tmp_path / "runs")])
    assert code in (0, 1, 2)


def test_recover_refuses_a_file_with_nothing_of_a_recording_and_writes_nothing(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(random.Random(0).randbytes(5000))
    out = tmp_path / "out.mcap"
    assert main(["recover", str(garbage), "-o", str(out)]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.mcap"]


@pytest.mark.parametrize(
    ("endpoint", "why"),
    [
        ("tcp/999.1.1.1:7447", "not an IPv4 address"),
        ("tcp/127.0.0.1", "expected host:port"),
        ("tcp/127.0.0.1:70000", "0..65535"),
        ("tpc/127.0.0.1:7447", "unknown protocol"),
        ("127.0.0.1:7447", "expected <protocol>/<address>"),
        ("tls/[::zz]:7447", "not an IPv6 address"),
        ("tcp/bad_host:7447", "not a host name"),
    ],
)
def test_validate_names_a_bad_endpoint(tmp_path, capsys, endpoint, why):
    recipe = tmp_path / "ep.yaml"
    recipe.write_text(
        f"vgr: 1\nname: ep\nprocesses:\n  main: {{listen: ['{endpoint}']}}\n"
        "stages:\n  source: {type: synthetic_cloud, params: {frames: 1}}\n"
    )
    assert main(["validate", str(recipe)]) == 2
    assert why in " ".join(capsys.readouterr()).replace("\n", " ")


@pytest.mark.parametrize(
    "endpoint", ["tcp/127.0.0.1:0", "tcp/localhost:7447", "tls/[::1]:7447", "quic/cell-3.plant:7447"]
)
def test_good_endpoints_pass(endpoint):
    assert endpoint_problem(endpoint) is None


@given(st.text(max_size=60))
def test_endpoint_checking_never_raises(text):
    assert endpoint_problem(text) is None or isinstance(endpoint_problem(text), str)
