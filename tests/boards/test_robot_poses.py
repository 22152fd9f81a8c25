"""Robot pose files for hand-eye from images: 4x4 rows, UR pose CSV and vgr JSON read to the same
poses; every malformed file is a RobotPoseFileError naming the line, never another exception."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine.transforms import T_from_rotvec, quat_xyzw_from_R, rotvec_from_R
from plugins.calibration.boards.robot_poses import RobotPoseFileError, load_robot_poses

POSES = np.stack([T_from_rotvec([0.1 * k, -0.2, 0.3 + 0.05 * k], [0.5 + 0.01 * k, -0.2, 0.8]) for k in range(4)])


def _rows(T: np.ndarray, sep: str = "\t") -> str:
    return "\n".join(sep.join(f"{v:.12f}" for v in t.ravel()) for t in T) + "\n"


def test_4x4_rows_ur_csv_and_json_give_the_same_poses(tmp_path):
    (tmp_path / "RobotPosesVec.txt").write_text(_rows(POSES))
    ur = ["x,y,z,rx,ry,rz"] + [",".join(f"{v:.12f}" for v in [*T[:3, 3], *rotvec_from_R(T[:3, :3])]) for T in POSES]
    (tmp_path / "ur.csv").write_text("\n".join(ur) + "\n")
    doc = {
        "length_unit": "mm",
        "poses": [
            {"position": (T[:3, 3] * 1e3).tolist(), "quat_xyzw": quat_xyzw_from_R(T[:3, :3]).tolist()} for T in POSES
        ],
    }
    (tmp_path / "poses.json").write_text(json.dumps(doc))
    (tmp_path / "list.json").write_text(json.dumps([T.tolist() for T in POSES]))
    for name in ("RobotPosesVec.txt", "ur.csv", "poses.json", "list.json"):
        np.testing.assert_allclose(load_robot_poses(tmp_path / name), POSES, atol=1e-9, err_msg=name)


def test_millimetres_and_comments(tmp_path):
    T = POSES.copy()
    T[:, :3, 3] *= 1e3
    (tmp_path / "p.txt").write_text("# flange poses\n" + _rows(T, sep=", "))
    np.testing.assert_allclose(load_robot_poses(tmp_path / "p.txt", length_unit="mm"), POSES, atol=1e-9)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "no poses"),
        ("1 2 3 4 5\n", "5 numbers"),
        (_rows(POSES[:1]) + "1 2 3 nope 5 6\n", ":2: not numbers"),
        (_rows(POSES[:1]) + "0.1 0.2 0.3 0.1 0.2 0.3\n", "where the first row has 16"),
        (" ".join(["2"] * 12 + ["0", "0", "0", "1"]) + "\n", "not a rotation"),
        (" ".join(map(str, [*np.eye(4).T.ravel()[:12].tolist(), 0.5, 0, 0, 1])) + "\n", "last row"),
        ("1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1\n", "finite"),
    ],
)
def test_bad_text_files_name_the_problem(tmp_path, text, message):
    (tmp_path / "p.txt").write_text(text)
    with pytest.raises(RobotPoseFileError, match=message):
        load_robot_poses(tmp_path / "p.txt")


def test_bad_json_and_missing_files(tmp_path):
    (tmp_path / "a.json").write_text("{not json")
    with pytest.raises(RobotPoseFileError, match="not JSON"):
        load_robot_poses(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps({"poses": [{"position": [0, 0, 0], "quat_xyzw": [0, 0, 0, 2]}]}))
    with pytest.raises(RobotPoseFileError, match="unit quaternion"):
        load_robot_poses(tmp_path / "b.json")
    with pytest.raises(RobotPoseFileError, match="no such file"):
        load_robot_poses(tmp_path / "missing.txt")


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.text(alphabet='0123456789.,;- \t\n#eEnaxyz[]{}":', max_size=300), st.sampled_from([".txt", ".json"]))
def test_garbage_is_refused_cleanly_or_read_as_poses(tmp_path, text, suffix):
    path = tmp_path / f"garbage{suffix}"
    path.write_text(text)
    try:
        T = load_robot_poses(path)
    except RobotPoseFileError:
        return
    assert T.ndim == 3 and T.shape[1:] == (4, 4) and np.all(np.isfinite(T))
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.transpose(R, (0, 2, 1)), np.broadcast_to(np.eye(3), R.shape), atol=3e-3)
