"""A recording whose bytes changed after it was written (a flipped bit on a disk, a bad copy) is
refused as damaged, by ``inspect`` and ``replay`` alike (exit 2: invalid input, not 1: a replay
that differs), and ``vgr recover`` salvages every chunk that is intact. Before, of 8 single-bit
flips 2 replayed as identical and 5 as "different"; a flip in the first chunk left nothing to recover."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from engine.cli.main import main
from engine.exit_codes import ExitCode
from engine.recording.reader import RecordingError, load, recover

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo recorded in small chunks (4 kB: many chunks, as a long run has)."""
    folder = tmp_path_factory.mktemp("damaged")
    recipe = folder / "demo.yaml"
    recipe.write_text(
        (ROOT / "recipes/demo.yaml").read_text().replace("\nstages:", "\nrecord: {chunk_size: 4096}\nstages:")
    )
    path = folder / "demo.mcap"
    argv = ["run", str(recipe), "-p", "source.n_points=400", "-p", "source.frames=10", "--no-progress"]
    assert main([*argv, "--record", str(path), "--runs-dir", str(folder / "runs")]) == ExitCode.OK
    return path


def flipped(path: Path, pos: int, bit: int, out: Path) -> Path:
    data = bytearray(path.read_bytes())
    data[pos] ^= 1 << bit
    out.write_bytes(bytes(data))
    return out


def test_every_flipped_bit_is_refused_as_damage(recording: Path, tmp_path: Path) -> None:
    size = recording.stat().st_size
    rng = random.Random(7)
    for k in range(30):
        bad = flipped(recording, rng.randrange(8, size - 8), rng.randrange(8), tmp_path / f"flip{k}.mcap")
        with pytest.raises(RecordingError):
            load(bad)


def test_replay_and_inspect_of_a_damaged_file_exit_2_saying_so(recording: Path, tmp_path: Path, capsys) -> None:
    bad = flipped(recording, recording.stat().st_size // 3, 3, tmp_path / "bad.mcap")
    for verb in ("replay", "inspect"):
        assert main([verb, str(bad), *(["--runs-dir", str(tmp_path)] if verb == "replay" else [])]) == ExitCode.INVALID
        said = capsys.readouterr()
        assert "damaged" in said.out + said.err


def test_recover_salvages_the_chunks_that_are_intact(recording: Path, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    with recording.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes  # type: ignore[union-attr]
    assert len(chunks) > 5
    whole = len([r for r in load(recording).records if r[0] == "msg"])
    inside_first = chunks[0].chunk_start_offset + chunks[0].chunk_length // 2  # (the schemas' and channels' chunk)
    report = recover(flipped(recording, inside_first, 2, tmp_path / "first.mcap"), tmp_path / "salvaged.mcap")
    assert "1 damaged chunk(s) skipped (number 1)" in report.error
    kept = len([r for r in load(tmp_path / "salvaged.mcap").records if r[0] == "msg"])
    assert whole - 10 < kept < whole  # one chunk's messages lost, every other kept
