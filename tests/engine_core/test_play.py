"""``vgr play`` against a plain zenoh subscriber: recorded order, recorded pace (relative spacing, scaled by
--rate), the --topics filter, a bounded --loop, an end of stream per topic, and nothing but data keys:
no _wire, no _control, no service query."""

from __future__ import annotations

import json
import signal
import struct
import subprocess
import threading
import time
from pathlib import Path

import jsonschema
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from process_helpers import ROOT, env, free_port, vgr

from engine.cli.json_output import schema
from engine.cli.main import main
from engine.recording.play import PlayError, Selection, data_messages, select
from engine.recording.reader import load

pytestmark = [pytest.mark.subprocess, pytest.mark.timeout(120)]
DEMO = ROOT / "recordings" / "demo.mcap"  # 10 frames at 30 Hz: /source/cloud, /move/cloud, /move/transform, events
ENV = struct.Struct("<4sBBHQq")
RECORDING = load(DEMO)


class Listener:
    """A zenoh session listening on loopback: every sample under vgr/** and every query it is sent."""

    def __init__(self) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        conf = zenoh.Config()
        conf.insert_json5("listen/endpoints", json.dumps([self.endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.samples: list[tuple[float, str, int, int]] = []  # (arrival, key, kind, seq)
        self.queries: list[str] = []
        self._lock = threading.Lock()
        self.session.declare_subscriber("vgr/**", self._on_sample)
        self.session.declare_queryable("vgr/**", lambda q: self.queries.append(str(q.key_expr)))

    def _on_sample(self, s: zenoh.Sample) -> None:
        _, kind, _, _, seq, _ = ENV.unpack_from(s.attachment.to_bytes())
        with self._lock:
            self.samples.append((time.monotonic(), str(s.key_expr), kind, seq))

    def play(self, *args: str) -> subprocess.CompletedProcess[str]:
        argv = vgr(
            "play", str(DEMO), "--connect", self.endpoint, "--wait-subscribers", "20", "--listen", "tcp/127.0.0.1:0"
        )
        return subprocess.run([*argv, *args], env=env(), capture_output=True, text=True, timeout=90)

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def listener():
    lis = Listener()
    yield lis
    lis.close()


def key_of(topic: str) -> str:
    return f"vgr/demo{topic}"


def test_plays_every_data_topic_in_order_at_the_recorded_pace(listener):
    done = listener.play("--rate", "0.5")
    assert done.returncode == 0, done.stderr
    recorded = data_messages(load(DEMO))
    data = [s for s in listener.samples if s[2] == 0]
    assert [(k, seq) for _, k, _, seq in data] == [(key_of(m.topic), m.seq) for m in recorded]
    ends = {k for _, k, kind, _ in listener.samples if kind == 1}
    assert ends == {key_of(m.topic) for m in recorded}  # each topic ended once the play was done
    assert all(k.split("/")[2][0] != "_" and len(k.split("/")) == 4 for _, k, _, _ in listener.samples)
    assert listener.queries == []  # no service called, nothing asked

    # pacing: the gaps keep their recorded proportions, and the whole is stretched by 1 / rate
    want = [(m.log_time - recorded[0].log_time) / 1e9 / 0.5 for m in recorded]
    got = [t - data[0][0] for t, *_ in data]
    assert got[-1] >= 0.9 * want[-1]  # never ahead of the schedule (the recorded span is 0.33 s)
    rel = [abs(g / got[-1] - w / want[-1]) for g, w in zip(got, want, strict=True)]
    assert max(rel) < 0.2, rel


def test_topics_filter_and_a_bounded_loop(listener):
    done = listener.play("--topics", "/move/transform", "--loop", "2", "--rate", "4")
    assert done.returncode == 0, done.stderr
    assert {k for _, k, _, _ in listener.samples} == {key_of("/move/transform")}
    seqs = [seq for _, _, kind, seq in listener.samples if kind == 0]
    assert seqs == list(range(1, 21))  # the second loop goes on counting: a subscriber sees no seq twice
    assert [(kind, seq) for _, _, kind, seq in listener.samples][-1] == (1, 21)  # end of stream after it
    assert "played 20 messages" in done.stdout


def test_start_and_end_select_a_time_slice(listener):
    done = listener.play("--topics", "/source/cloud", "--start", "0.1", "--end", "0.2", "--rate", "4")
    assert done.returncode == 0, done.stderr
    t0 = data_messages(load(DEMO))[0].log_time
    want = [m.seq for m in load(DEMO).messages("/source/cloud") if 0.1e9 <= m.log_time - t0 <= 0.2e9]
    assert [seq for _, _, kind, seq in listener.samples if kind == 0] == want and len(want) == 3


def test_the_json_document_says_what_was_played_and_validates(listener):
    r = listener.play("--topics", "/source/cloud", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)  # strict: the whole of stdout is one document
    jsonschema.validate(doc, schema("play"))
    assert (doc["run_id"], doc["topics"], doc["exit_code"]) == ("demo", ["/source/cloud"], 0)
    assert doc["messages_played"] == len(list(RECORDING.messages("/source/cloud")))


def test_a_refused_play_prints_the_invalid_document(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    assert main(["play", str(DEMO), "--rate", "0", "--json"]) == 2
    doc = json.loads(capsys.readouterr().out)
    jsonschema.validate(doc, schema("invalid"))
    assert doc["verb"] == "play" and "rate" in doc["error"]


def test_refusals_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    assert main(["play", str(DEMO), "--topics", "/nope/x"]) == 2
    assert "no topic /nope/x" in capsys.readouterr().err
    assert main(["play", str(DEMO), "--rate", "0"]) == 2
    assert main(["play", str(Path(tmp_path, "missing.mcap"))]) == 2
    assert main(["play", str(DEMO), "--loop", "-1", "--listen", "tcp/127.0.0.1:0"]) == 2


def test_a_play_is_found_by_vgr_topics_and_ends_on_ctrl_c(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # the play's private socket goes there
    proc = subprocess.Popen(vgr("play", str(DEMO), "--loop"), env=env(), text=True)
    try:
        socket = tmp_path / "vgr" / "demo" / "play.sock"
        deadline = time.monotonic() + 60
        while not socket.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the play did not start"
            time.sleep(0.05)
        assert main(["topics", "list", "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["run_id"] == "demo" and {t["process"] for t in doc["topics"]} == {"play"}
        assert {t["topic"] for t in doc["topics"]} == {m.topic for m in data_messages(load(DEMO))}
        assert main(["play", str(DEMO)]) == 2  # a second play of run demo here: refused without --run-id
        assert "--run-id" in capsys.readouterr().err
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 130
    assert not socket.exists()  # closed with the play: the next one may take the name


@settings(max_examples=100, deadline=None)
@given(
    st.one_of(st.none(), st.lists(st.sampled_from(["/source/cloud", "/move/cloud", "/x/y", "move/transform"]))),
    st.one_of(st.none(), st.floats(-1, 1, allow_nan=False)),
    st.one_of(st.none(), st.floats(-1, 1, allow_nan=False)),
)
def test_any_selection_is_played_within_its_bounds_or_refused(topics, start, end):
    try:
        msgs = select(RECORDING, Selection(topics, start, end))
    except PlayError:
        return
    t0 = data_messages(RECORDING)[0].log_time
    assert msgs and all(start is None or m.log_time - t0 >= start * 1e9 - 1 for m in msgs)
    assert all(end is None or m.log_time - t0 <= end * 1e9 + 1 for m in msgs)
    assert topics is None or {m.topic for m in msgs} <= {"/" + t.strip("/") for t in topics}


def test_a_guidance_recording_plays_its_plugin_message_types(listener):
    """A guidance run's GuidanceResult is a plugin's type: play loads the recorded recipe's plugins."""
    dock = ROOT / "recordings" / "eye_in_hand_dock.mcap"
    argv = vgr("play", str(dock), "--connect", listener.endpoint, "--wait-subscribers", "20")
    argv += ["--listen", "tcp/127.0.0.1:0", "--topics", "/guidance/result", "--rate", "1000"]
    done = subprocess.run(argv, env=env(), capture_output=True, text=True, timeout=90)
    assert done.returncode == 0, done.stderr
    run_id = load(dock).metadata["vgr.run"]["run_id"]
    kinds = [kind for _, key, kind, _ in listener.samples if key == f"vgr/{run_id}/guidance/result"]
    assert kinds[:1] == [0] and len(kinds) == 2, listener.samples  # the result, then the end of stream
