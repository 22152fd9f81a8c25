"""What ``vgr gap --depth`` reads: a captures file round-trips, a folder of files is one set, a vgr
recording of a simulated camera gives the same captures (the true target pose with
``--target-frame``, a fitted plane without); bad input (too few captures, wrong shapes, no K,
NaN-only frames, a pose that is no rotation, a recording without depth) is refused with exit code 2,
a ``vgr.invalid/1`` document and a message that says what is wrong, also for any corruption
hypothesis makes of a captures file; a real recording of the simulated cell (``vgr run`` of the board
hand-eye recipe with its depth images) is read with the board's true pose."""

from __future__ import annotations

import numpy as np
import pytest
from depth_gap_helpers import invalid, run_json, write_recording
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine.cli.main import main
from plugins.model_gap.depth.data import DepthGapInputError, SigmaLaw, prepare
from plugins.model_gap.depth.inputs import FORMAT, load_captures, write_captures
from plugins.sim.model_gap.depth_captures import simulate_captures


@pytest.fixture(scope="module")
def sim():
    return simulate_captures("range_bias", n=8, seed=9, stated_noise=True)


def test_a_captures_file_round_trips(sim, tmp_path):
    write_captures(tmp_path / "c.npz", sim)
    back = load_captures([str(tmp_path / "c.npz")])
    assert [f.name for f in back.frames] == [f.name for f in sim.frames] and back.size == sim.size
    assert np.array_equal(back.K, sim.K) and back.sigma == sim.sigma
    for a, b in zip(back.frames, sim.frames, strict=True):
        assert np.array_equal(a.depth, b.depth.astype(np.float32), equal_nan=True)
        assert np.allclose(a.T_cam_target, b.T_cam_target)
    override = load_captures([str(tmp_path / "c.npz")], sigma=SigmaLaw(1e-3))
    assert override.sigma == SigmaLaw(1e-3)


def test_a_folder_of_files_is_one_set_in_name_order(sim, tmp_path):
    for k, part in enumerate((sim.frames[:3], sim.frames[3:])):
        write_captures(tmp_path / f"part{k}.npz", type(sim)(list(part), sim.K, sim.size))
    (tmp_path / "notes.txt").write_text("not a captures file")
    back = load_captures([str(tmp_path)])
    assert [f.name for f in back.frames] == [f.name for f in sim.frames]


def test_a_recording_gives_the_same_captures_and_the_true_pose_with_a_target_frame(sim, tmp_path):
    rec = write_recording(tmp_path / "run.mcap", sim)
    posed = load_captures([str(rec)], target_frame="plate")
    assert len(posed.frames) == 8 and np.array_equal(posed.K, sim.K) and posed.size == sim.size
    for a, b in zip(posed.frames, sim.frames, strict=True):
        assert np.allclose(a.T_cam_target, b.T_cam_target, atol=1e-12)
        assert np.array_equal(a.depth, b.depth.astype(np.float32), equal_nan=True)
    assert all(f.T_cam_target is None for f in load_captures([str(rec)]).frames)  # no frame: plane fitted
    with pytest.raises(DepthGapInputError, match="no true pose of 'board'"):
        load_captures([str(rec)], target_frame="board")
    with pytest.raises(DepthGapInputError, match="no Image topic '/camera/image'"):
        load_captures([str(rec)], topic="/camera/image")


def test_the_cli_reads_a_recording(sim, tmp_path, capsys):
    more = simulate_captures("range_bias", n=16, seed=9)  # 13 or more name an effect at alpha 1e-3
    code, doc = run_json(
        capsys, "--depth", str(write_recording(tmp_path / "run.mcap", more)), "--target-frame", "plate"
    )
    assert code == 0 and doc["target"] == "known" and doc["named"] == ["range_bias"], doc["reason"]


def _file(tmp_path, name: str, **arrays) -> str:
    np.savez(tmp_path / name, **arrays)
    return str(tmp_path / name)


def test_bad_input_is_refused_with_what_is_wrong(sim, tmp_path, capsys):
    depth = np.stack([f.depth for f in sim.frames])
    poses = np.stack([f.T_cam_target for f in sim.frames])
    few = _file(tmp_path, "few.npz", depth=depth[:5], K=sim.K, T_cam_target=poses[:5])
    assert "at least 6" in invalid(capsys, "--depth", few)["error"]
    assert "no 'K' array" in invalid(capsys, "--depth", _file(tmp_path, "nok.npz", depth=depth))["error"]
    assert (
        "K of shape (2, 3)" in invalid(capsys, "--depth", _file(tmp_path, "k.npz", depth=depth, K=sim.K[:2]))["error"]
    )
    flat = _file(tmp_path, "flat.npz", depth=depth.reshape(8, -1)[0], K=sim.K)
    assert "depth of shape (4800,)" in invalid(capsys, "--depth", flat)["error"]
    wrong = _file(tmp_path, "poses.npz", depth=depth, K=sim.K, T_cam_target=poses[:7])
    assert "one pose per capture" in invalid(capsys, "--depth", wrong)["error"]
    nan = _file(tmp_path, "nan.npz", depth=np.full_like(depth, np.nan), K=sim.K, T_cam_target=poses)
    assert "no valid pixel" in invalid(capsys, "--depth", nan)["error"]
    half = depth.copy()
    half[:3] = np.nan  # three NaN-only frames leave 5 usable captures
    msg = invalid(capsys, "--depth", _file(tmp_path, "half.npz", depth=half, K=sim.K, T_cam_target=poses))["error"]
    assert "5 usable captures" in msg and "3 left out" in msg and "no valid pixel" in msg
    skew = poses.copy()
    skew[2, :3, :3] *= 1.1
    bad_pose = _file(tmp_path, "skew.npz", depth=depth, K=sim.K, T_cam_target=skew)
    assert "not a rotation" in invalid(capsys, "--depth", bad_pose)["error"]
    assert "no such file" in invalid(capsys, "--depth", str(tmp_path / "nope.npz"))["error"]
    (tmp_path / "empty").mkdir()
    assert "holds no .npz" in invalid(capsys, "--depth", str(tmp_path / "empty"))["error"]
    assert "format 'other/1'" in invalid(capsys, "--depth", _file(tmp_path, "f.npz", format="other/1"))["error"]


def test_a_recording_whose_depth_topic_is_not_found_is_refused_or_named(sim, tmp_path, capsys):
    rec = write_recording(tmp_path / "run.mcap", sim, port="range")
    assert "0 depth image topics" in invalid(capsys, "--depth", str(rec))["error"]
    assert "no Image topic '/robot/depth'" in invalid(capsys, "--depth", str(rec), "--topic", "/robot/depth")["error"]
    back = load_captures([str(rec)], topic="/camera/range", target_frame="plate")  # named: read
    assert len(back.frames) == 8 and all(f.T_cam_target is not None for f in back.frames)


_KINDS = "drop_K K_shape K_nan depth_ndim all_nan all_zero few poses_count names_count fx_zero D_length"
_CORRUPTIONS = st.sampled_from(_KINDS.split())


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=_CORRUPTIONS, n=st.integers(1, 8), scale=st.floats(-2.0, 2.0, allow_nan=False))
def test_any_corrupted_captures_file_is_refused_as_invalid_json(sim, tmp_path_factory, capsys, kind, n, scale):
    depth = np.stack([f.depth for f in sim.frames])
    arrays = {"format": np.array(FORMAT), "depth": depth, "K": sim.K.copy()}
    arrays["T_cam_target"] = np.stack([f.T_cam_target for f in sim.frames])
    if kind == "drop_K":
        del arrays["K"]
    elif kind == "K_shape":
        arrays["K"] = np.eye(n % 3 + 2) if n % 3 != 1 else np.eye(4)
    elif kind == "K_nan":
        arrays["K"][n % 2, 2] = np.nan
    elif kind == "depth_ndim":
        arrays["depth"] = depth.reshape(-1) if n % 2 else depth[..., None]
    elif kind == "all_nan":
        arrays["depth"] = np.full_like(depth, np.nan)
    elif kind == "all_zero":
        arrays["depth"] = np.zeros_like(depth) + min(scale, 0.0)  # zero or negative: invalid
    elif kind == "few":
        arrays["depth"], arrays["T_cam_target"] = depth[: n % 6], arrays["T_cam_target"][: n % 6]
    elif kind == "poses_count":
        arrays["T_cam_target"] = arrays["T_cam_target"][: n % 8] if n % 8 else arrays["T_cam_target"][:, :3]
    elif kind == "names_count":
        arrays["names"] = np.array([f"c{k}" for k in range(n + 8)])
    elif kind == "fx_zero":
        arrays["K"][0, 0] = min(scale, 0.0)
    elif kind == "D_length":
        arrays["D"] = np.full((1, 2, 3, 6, 7)[n % 5], scale)
    path = tmp_path_factory.mktemp("bad") / "c.npz"
    np.savez(path, **arrays)
    expected = {
        "drop_K": "no 'K' array", "K_shape": "K of shape", "K_nan": "K must be a finite 3x3",
        "depth_ndim": "depth of shape", "all_nan": "no valid pixel", "all_zero": "no valid pixel",
        "few": "depth of shape" if n % 6 == 0 else "at least 6", "poses_count": "one pose per capture",
        "names_count": f"{n + 8} names for 8 captures", "fx_zero": "fx, fy > 0", "D_length": "distortion D must be",
    }[kind]  # fmt: skip
    assert expected in invalid(capsys, "--depth", str(path))["error"]


def test_a_recording_of_the_simulated_cell_is_read_with_the_true_board_pose(tmp_path, capsys):
    """A real ``vgr run`` of the simulated cell (the board hand-eye recipe, its depth images
    published): the board plate is the target, its true pose from ``truth/part_poses``; the ranges
    it predicts agree with the measured ones to the simulated noise (0.2 mm), and 12 captures are too
    few to name anything (the note says how many are needed)."""
    rec = tmp_path / "cell.mcap"
    recipe = "recipes/calibrate_handeye_board_sim.yaml"
    assert (
        main(["run", recipe, "--record", str(rec), "-p", "camera.publish_depth=true", "--runs-dir", str(tmp_path)]) == 0
    )
    capsys.readouterr()
    caps = load_captures([str(rec)], target_frame="board")
    assert len(caps.frames) == 12 and caps.size == (320, 240)
    px = prepare(caps, "known")
    assert abs(float(np.median(px.residual))) < 5e-5  # metres: the pose and the depth frames line up
    assert 1.4826 * float(np.median(np.abs(px.residual))) == pytest.approx(2e-4, rel=0.2)
    code, doc = run_json(capsys, "--depth", str(rec), "--target-frame", "board")
    assert code == 0 and doc["verdict"] == "no_gap" and any("at least 13 captures" in n for n in doc["notes"])
