"""Recording and replay: bit-identical replays, located differences, Foxglove-readable channels."""

from __future__ import annotations

import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from recipe_helpers import graph_from

from engine.cli.main import main
from engine.recording import recorder as recorder_mod
from engine.recording.reader import inspect, load
from engine.recording.recorder import Recorder
from engine.recording.replay import replay
from engine.recording.replay_update import write_updated
from engine.run.runner import Runner

pytestmark = pytest.mark.timeout(120)

PIPELINE = """
name: pipeline
plugins: [stage_fixtures]
seed: 11
clock: {clock}
stages:
  src:   {{type: t_counter, params: {{n: 40}}}}
  other: {{type: t_counter, params: {{n: 25}}}}
  merge: {{type: t_merge, inputs: {{a: src.out, b: other.out}}}}
  noisy: {{type: t_noisy_cloud, inputs: {{in: merge.out}}, params: {{n: 30, scale: 0.5}}}}
  cent:  {{type: t_threaded_centroid, inputs: {{cloud: noisy.cloud}}}}
  echo:  {{type: t_echo}}
  call:  {{type: t_caller, inputs: {{in: src.out}}, uses: {{svc: echo.echo}}}}
  sink:  {{type: t_collector, inputs: {{in: call.out}}}}
"""


def record(tmp_path: Path, text: str, name: str = "run.mcap", **kw) -> Path:
    graph = graph_from(textwrap.dedent(text))
    path = tmp_path / name
    rec = Recorder(path, graph.recipe.record, graph.loaded, ["builtin", "stage_fixtures"])
    summary = Runner(graph, observers=[rec], **kw).run()
    assert summary.ok, summary.stop_reason
    assert summary.artifacts["recording"] == str(path) and rec.error is None
    return path


@pytest.mark.parametrize("clock", ["sim", "wall"])
def test_replay_is_bit_identical_ten_times(tmp_path, clock):
    path = record(tmp_path, PIPELINE.format(clock=clock))
    first = None
    for _ in range(10):
        report, _, _ = replay(path)
        assert report.ok and not report.failures
        assert {v.topic for v in report.streams} == {"/merge/out", "/noisy/cloud", "/cent/centroid", "/call/out"}
        assert all(v.verdict == "identical" for v in (*report.streams, *report.requests))
        outputs = {t: [o.payload for o in outs] for t, outs in report.outputs.items()}
        if first is None:
            first = outputs
        assert outputs == first
    assert set(report.rerun) == {"merge", "noisy", "cent", "call", "sink"}  # sources and the echo device play back
    assert len(first["/noisy/cloud"]) == 65 and len(first["/call/out"]) == 40


def test_changed_solver_parameter_is_reported_with_its_location(tmp_path, capsys):
    path = record(tmp_path, PIPELINE.format(clock="sim"))
    report, _, _ = replay(path, overrides=["noisy.scale=0.6"])
    bad = {v.topic: v for v in report.streams if v.verdict == "different"}
    assert set(bad) == {"/noisy/cloud", "/cent/centroid"}
    assert bad["/noisy/cloud"].first_difference.startswith("/noisy/cloud[seq 1].points[0, 0]: recorded ")
    assert bad["/cent/centroid"].first_difference.startswith("/cent/centroid[seq 1].T[")
    assert not report.ok
    assert main(["replay", str(path), "-p", "noisy.scale=0.6"]) == 1
    text = capsys.readouterr().out
    assert "different" in text and "/noisy/cloud[seq 1].points[0, 0]" in text


def test_update_rewrites_the_golden_recording(tmp_path):
    path = record(tmp_path, PIPELINE.format(clock="sim"))
    report, rec, graph = replay(path, overrides=["noisy.scale=0.6"])
    write_updated(report, rec, path, graph.loaded.text, graph.loaded.overrides)
    assert load(path).overrides == ["noisy.scale=0.6"]  # the golden now carries the parameter it was made with
    again, _, _ = replay(path)
    assert again.ok and all(v.verdict == "identical" for v in again.streams)
    assert again.outputs["/noisy/cloud"][0].payload == report.outputs["/noisy/cloud"][0].payload


def test_update_refuses_when_a_stage_failed_during_the_replay(tmp_path, capsys):
    """A stage that fails stops producing: rewriting the golden then would drop its later outputs."""
    path = record(tmp_path, PIPELINE.format(clock="sim"))
    before = path.read_bytes()
    assert main(["replay", str(path), "-p", "noisy.n=-100", "--update"]) == 2  # (a negative cloud size raises)
    out = capsys.readouterr()
    assert "stage failure during replay" in out.out and "a stage failed during the replay" in out.err
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == [path.name]  # nothing left beside it


def test_a_writer_that_cannot_finish_in_time_is_reported_not_hidden(tmp_path, monkeypatch):
    """The end of a run waits a bounded time for the recorder's backlog; if the writer is still busy
    the run says the recording is incomplete instead of handing over a file without its end."""
    monkeypatch.setattr(recorder_mod, "WRITER_FINISH_TIMEOUT_S", 0.05)
    slow = recorder_mod.Recorder._write
    monkeypatch.setattr(recorder_mod.Recorder, "_write", lambda self, item: (time.sleep(0.02), slow(self, item)))
    graph = graph_from(textwrap.dedent(PIPELINE.format(clock="sim")))
    rec = Recorder(tmp_path / "slow.mcap", graph.recipe.record, graph.loaded, ["builtin", "stage_fixtures"])
    summary = Runner(graph, observers=[rec]).run()
    assert "did not finish within 0.05 s" in summary.artifacts["recording_error"]


def test_recording_opens_with_foxglove_schemas(tmp_path):
    path = record(
        tmp_path,
        """
    name: fox
    clock: sim
    stages:
      source: {type: synthetic_cloud, params: {n_points: 100, frames: 3}}
      move: {type: transform_cloud, inputs: {cloud: source.cloud}, params: {translation_m: [0, 0, 1]}}
    """,
    )
    seen = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])  # uses only the schemas in the file
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append((schema.name, decoded))
    name, cloud = seen["/move/cloud"][0]
    assert name == "foxglove.PointCloud" and cloud.frame_id == "camera" and cloud.point_stride == 12
    pts = np.frombuffer(cloud.data, np.float32).reshape(-1, 3)
    assert pts.shape == (100, 3) and abs(pts[:, 2].mean() - 1.0) < 0.05
    name, pose = seen["/move/transform"][0]
    assert name == "foxglove.PoseInFrame" and pose.pose.position.z == 1.0 and pose.pose.orientation.w == 1.0


def test_recording_holds_recipe_versions_seed_and_service_exchanges(tmp_path):
    path = record(tmp_path, PIPELINE.format(clock="sim"))
    rec = load(path)
    assert rec.metadata["vgr.run"]["seed"] == "11" and "t_noisy_cloud" in rec.recipe_text
    assert rec.metadata["vgr.versions"]["vgr"] and "stage_fixtures" in rec.metadata["vgr.versions"]["plugins"]
    assert "resolved_json" in rec.metadata["vgr.recipe"] and rec.attachments["recipe.yaml"].decode() == rec.recipe_text
    ex = [r[1] for r in rec.records if r[0] == "svc"]
    assert len(ex) == 40 and all(e.provider == "echo" and e.reply for e in ex)
    info = inspect(rec)
    counts = {t["topic"]: t["count"] for t in info["topics"]}
    assert counts["/src/out"] == 40 and counts["/noisy/cloud"] == 65 and info["deliveries"] > 0
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.chunk_count >= 1 and summary.chunk_indexes  # chunked and indexed


def test_replay_cli_and_inspect_cli(tmp_path, capsys):
    path = record(tmp_path, PIPELINE.format(clock="sim"))
    assert main(["replay", str(path)]) == 0
    assert "0 different" in capsys.readouterr().out
    assert main(["inspect", str(path)]) == 0
    assert "/noisy/cloud" in capsys.readouterr().out


def test_damaged_or_foreign_files_give_clear_errors(tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    assert main(["replay", str(bad)]) == 2
    assert "cannot read" in capsys.readouterr().err
    assert main(["inspect", str(tmp_path / "missing.mcap")]) == 2
    assert "no such recording" in capsys.readouterr().err


def test_record_to_an_existing_file_is_refused_and_the_file_kept(tmp_path, capsys):
    """`vgr run --record FILE` never replaces a file: exit 2 before the run, the file as it was."""
    golden = tmp_path / "golden.mcap"
    golden.write_bytes(b"the old golden")
    assert main(["run", "recipes/demo.yaml", "-p", "source.frames=3", "--no-progress", "--record", str(golden)]) == 2
    assert "exists: a run never replaces a file" in capsys.readouterr().err
    assert golden.read_bytes() == b"the old golden" and sorted(p.name for p in tmp_path.iterdir()) == ["golden.mcap"]


def test_a_recorder_given_an_existing_file_replaces_it_only_when_the_run_ends_well(tmp_path):
    """The library's Recorder (what `vgr replay --update` relies on for goldens) records beside an
    existing file and renames over it at a good end; a failed run leaves the old file as it was."""
    golden = tmp_path / "golden.mcap"
    graph = graph_from(textwrap.dedent(PIPELINE.format(clock="sim")))
    golden.write_bytes(b"the old golden")
    assert (
        Runner(graph, observers=[Recorder(golden, graph.recipe.record, graph.loaded, ["builtin", "stage_fixtures"])])
        .run()
        .ok
    )
    assert load(golden).records and sorted(p.name for p in tmp_path.iterdir()) == ["golden.mcap"]

    golden.write_bytes(b"the old golden")
    graph = graph_from(textwrap.dedent(PIPELINE.format(clock="sim")), ["noisy.n=-100"])  # noisy fails at run time
    rec = Recorder(golden, graph.recipe.record, graph.loaded, ["builtin", "stage_fixtures"])
    summary = Runner(graph, observers=[rec]).run()
    assert not summary.ok and golden.read_bytes() == b"the old golden"
    assert summary.artifacts["recording"] == str(tmp_path / "golden.new.mcap") and "left as it was" in str(
        summary.artifacts["recording_kept"]
    )
    assert load(tmp_path / "golden.new.mcap").records  # the failed run's own recording, complete


def test_record_paths_of_several_processes_and_runs_never_collide(tmp_path, monkeypatch):
    from datetime import datetime as real_datetime

    from engine.recipe.model import RecordSettings
    from engine.recording.recorder import resolve_path

    class Frozen(real_datetime):  # two runs in the same second
        @classmethod
        def now(cls, tz=None):
            return real_datetime(2026, 1, 2, 3, 4, 5)

    monkeypatch.setattr(recorder_mod, "datetime", Frozen)
    in_dir = RecordSettings(path=str(tmp_path) + "/")
    first = resolve_path(in_dir, "r", "main")
    first.write_bytes(b"run 1")
    assert resolve_path(in_dir, "r", "main") not in (first,)  # a second run that second gets its own file
    one_file = RecordSettings(path=str(tmp_path / "cell.mcap"))
    assert resolve_path(one_file, "r", "main") == tmp_path / "cell.mcap"
    assert resolve_path(one_file, "r", "camera_host") == tmp_path / "cell-camera_host.mcap"
