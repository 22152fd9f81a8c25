"""``vgr topics list|echo|hz`` against a real running run on loopback (the demo recipe on the wall clock,
listening on its private socket, found there), and their refusals: no run, several runs, no topic."""

from __future__ import annotations

import base64
import json
import signal
import subprocess
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from process_helpers import demo_streaming, env, vgr

from engine.cli.main import main
from engine.messages import codec
from engine.messages.schemas import descriptor_set
from engine.recipe.model import ZenohSettings
from engine.recording.topics import NoRunError, Run, SchemaPool, decode_sample, rates
from engine.transport import discovery
from engine.transport.bus import Bus

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """A demo run streaming at 20 Hz for up to a minute on its private socket, in a socket folder of
    its own (XDG_RUNTIME_DIR, for this process too); the socket's endpoint."""
    runtime = tmp_path_factory.mktemp("xdg")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_RUNTIME_DIR", str(runtime))
        runs = str(tmp_path_factory.mktemp("runs"))
        proc = subprocess.Popen(
            vgr(*demo_streaming(20, 1200, 200), "--no-record", "--listen", "private", "--runs-dir", runs),
            env=env(),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        socket = runtime / "vgr" / "demo" / "main.sock"
        deadline = time.monotonic() + 60
        while not socket.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the run did not start"
            time.sleep(0.1)
        yield f"unixsock-stream/{socket}"
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 130


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(argv))
    got = capsys.readouterr()
    return code, got.out, got.err


def test_list_names_every_output_with_its_type_schema_and_stage(live, capsys):
    code, out, _ = run_cli(capsys, "topics", "list", "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["run_id"] == "demo"
    rows = {t["topic"]: (t["type"], t["schema"], t["stage"], t["process"], t["key"]) for t in doc["topics"]}
    assert rows["/source/cloud"] == ("PointCloud", "foxglove.PointCloud", "source", "main", "vgr/demo/source/cloud")
    assert rows["/move/transform"] == ("PoseStamped", "foxglove.PoseInFrame", "move", "main", "vgr/demo/move/transform")
    assert set(rows) == {
        "/source/cloud",
        "/source/events",
        "/move/cloud",
        "/move/events",
        "/move/transform",
        "/stats/events",
    }


def test_echo_prints_count_decoded_messages(live, capsys):
    code, out, _ = run_cli(capsys, "topics", "echo", "move.transform", "--count", "3", "--json")
    assert code == 0
    docs = [json.loads(line) for line in out.splitlines()]
    assert len(docs) == 3
    assert [d["seq"] for d in docs] == list(range(docs[0]["seq"], docs[0]["seq"] + 3))
    pos = docs[0]["message"]["pose"]["position"]
    assert (pos["x"], pos["y"], pos["z"], docs[0]["type"]) == (0.01, -0.005, 0.5, "PoseStamped")
    code, out, _ = run_cli(capsys, "topics", "echo", "/source/cloud", "--json")
    (cloud,) = [json.loads(line) for line in out.splitlines()]
    assert cloud["message"]["data"] == f"<{200 * 12} bytes>" and cloud["message"]["point_stride"] == 12


def test_hz_counts_the_messages_of_each_window(live, capsys):
    argv = ["topics", "hz", "/source/cloud", "/move/cloud", "--window", "0.5", "--windows", "2", "--json"]
    code, out, _ = run_cli(capsys, *argv)
    assert code == 0
    docs = [json.loads(line) for line in out.splitlines()]
    assert [d["topic"] for d in docs] == ["/source/cloud", "/move/cloud"] * 2
    assert all(d["messages"] >= 2 and d["rate_hz"] > 0 for d in docs)


def test_several_runs_need_a_run_id_and_an_unknown_one_is_refused(live, capsys):
    from engine.transport.endpoints import private_socket

    with Bus(ZenohSettings(listen=[private_socket("other", "main")])) as other:  # a second run of this user
        discovery.announce(other, "other", "main", [discovery.topic_info("other", "s", "p", "Event", "vgr.v1.Event")])
        code, _, err = run_cli(capsys, "topics", "list")
        assert code == 2 and "several runs" in err and "demo, other" in err
        code, out, _ = run_cli(capsys, "topics", "list", "--json", "--run-id", "other")
        assert code == 0 and [t["topic"] for t in json.loads(out)["topics"]] == ["/s/p"]
        code, _, err = run_cli(capsys, "topics", "list", "--run-id", "nope", "--connect", live)
        assert code == 2 and "no run 'nope'" in err and "runs found: demo" in err


def test_no_run_and_no_topic_exit_2(live, tmp_path, capsys, monkeypatch):
    code, _, err = run_cli(capsys, "topics", "echo", "/move/nothing")
    assert code == 2 and "no topic '/move/nothing'" in err and "/move/cloud" in err
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # a user with no run
    code, _, err = run_cli(capsys, "topics", "list")
    assert code == 2 and "no vgr run found" in err and "--listen private" in err


def test_rates_from_arrival_times():
    (r,) = rates({"/a": [0.0, 0.1, 0.2, 0.4]}, 1.0)
    assert r.messages == 4 and r.rate_hz == pytest.approx(7.5) and r.gap_max_ms == pytest.approx(200.0)
    assert r.gap_min_ms == pytest.approx(100.0)
    (lone,) = rates({"/b": [0.3]}, 1.0)
    assert lone.rate_hz is None and lone.messages == 1


RUN = Run("r", [{"process": "main", "topics": [{"topic": "/a/b", "key": "vgr/r/a/b", "schema": "vgr.v1.Event"}]}])


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=20))
def test_any_topic_name_is_found_or_refused(name):
    try:
        assert RUN.topic(name)["topic"] == "/a/b"
    except NoRunError as exc:
        assert "no topic" in str(exc)


POOL = SchemaPool({"vgr.v1.Event": base64.b64encode(descriptor_set("vgr.v1.Event")).decode()})


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40), st.binary(max_size=60), st.booleans())
def test_garbage_samples_raise_codec_errors_only(att, payload, valid_envelope):
    if valid_envelope:  # a well-formed envelope: the payload alone is garbage
        att = codec.encode_envelope(codec.Envelope(codec.Kind.DATA, 1, 2, "Event"))
    try:
        doc = decode_sample(RUN.topics[0], payload, att, POOL)
    except codec.CodecError:  # a ValueError: protobuf's DecodeError (not one) must not escape
        return
    assert doc["topic"] == "/a/b"


def test_a_second_session_on_a_held_private_socket_is_told_to_take_another_run_id(tmp_path, monkeypatch):
    from engine.recipe.model import ZenohSettings
    from engine.transport.bus import Bus, BusError
    from engine.transport.endpoints import private_socket

    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    tmp_path.chmod(0o700)
    endpoint = private_socket("same-id", "main")
    with Bus(ZenohSettings(listen=[endpoint])), pytest.raises(BusError) as err:
        Bus(ZenohSettings(listen=[endpoint]))
    message = str(err.value)
    assert "another --run-id" in message and endpoint.split("/", 1)[1] in message
    assert "unicast.rs" not in message and "EAGAIN" not in message
