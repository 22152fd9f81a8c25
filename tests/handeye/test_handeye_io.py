"""Plain-file loaders: MoveIt JSON, vgr JSON and CSV (quaternion or rotation-vector columns, m or mm)."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from shared_data import SHARED

from plugins.solvers.handeye import HandEyeInputError
from plugins.solvers.handeye import simulate as sim
from plugins.solvers.handeye.io import VGR_FORMAT, load_pose_pairs, write_pose_pairs_json

MOVEIT = SHARED / "moveit_calibration" / "pose_samples.json"
SCENE = sim.viewing_scene(np.random.default_rng(50), 6, "eye_in_hand")


def test_moveit_pose_samples_load():
    s = load_pose_pairs(MOVEIT)
    assert s.T_base_tcp.shape == (50, 4, 4) and s.T_cam_target.shape == (50, 4, 4)
    raw = json.loads(MOVEIT.read_text())
    assert np.allclose(s.T_base_tcp[7], raw[7][0]) and np.allclose(s.T_cam_target[7], raw[7][1])


def test_vgr_json_round_trip(tmp_path):
    path = tmp_path / "samples.json"
    write_pose_pairs_json(path, SCENE.T_base_tcp, SCENE.T_cam_target, setup="eye_in_hand")
    s = load_pose_pairs(path)
    assert np.allclose(s.T_base_tcp, SCENE.T_base_tcp) and np.allclose(s.T_cam_target, SCENE.T_cam_target)
    assert s.setup == "eye_in_hand" and s.ids == [str(k) for k in range(6)]


def test_vgr_json_pose_objects_in_mm(tmp_path):
    samples = []
    for k in range(6):
        q = Rotation.from_matrix(SCENE.T_base_tcp[k, :3, :3]).as_quat()
        rv = Rotation.from_matrix(SCENE.T_cam_target[k, :3, :3]).as_rotvec()
        samples.append(
            {
                "id": f"p{k}",
                "T_base_tcp": {
                    "position": (SCENE.T_base_tcp[k, :3, 3] * 1000).tolist(),
                    "quat_xyzw": q.tolist(),
                },
                "T_cam_target": {
                    "position": (SCENE.T_cam_target[k, :3, 3] * 1000).tolist(),
                    "rotvec": rv.tolist(),
                },
            }
        )
    path = tmp_path / "mm.json"
    path.write_text(json.dumps({"format": VGR_FORMAT, "length_unit": "mm", "samples": samples}))
    s = load_pose_pairs(path)
    assert np.allclose(s.T_base_tcp, SCENE.T_base_tcp) and np.allclose(s.T_cam_target, SCENE.T_cam_target)
    assert s.ids[2] == "p2"
    with pytest.raises(HandEyeInputError, match="length_unit"):
        load_pose_pairs(path, length_unit="m")


def _write_csv(path: Path, rot: str, unit_scale: float = 1.0) -> None:
    def cols(prefix: str) -> list[str]:
        tail = ["qx", "qy", "qz", "qw"] if rot == "quat" else ["rx", "ry", "rz"]
        return [prefix + c for c in ["x", "y", "z", *tail]]

    def vals(T: np.ndarray) -> list[float]:
        r = Rotation.from_matrix(T[:3, :3])
        return [*(T[:3, 3] * unit_scale), *(r.as_quat() if rot == "quat" else r.as_rotvec())]

    lines = ["# robot and camera poses", ",".join(["id", *cols("base_tcp_"), *cols("cam_target_")])]
    for k in range(6):
        row = [f"s{k}", *vals(SCENE.T_base_tcp[k]), *vals(SCENE.T_cam_target[k])]
        lines.append(",".join(str(v) for v in row))
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("rot", ["quat", "rotvec"])
def test_csv_quaternion_and_rotation_vector_columns(tmp_path, rot):
    path = tmp_path / "s.csv"
    _write_csv(path, rot)
    s = load_pose_pairs(path)
    assert np.allclose(s.T_base_tcp, SCENE.T_base_tcp) and np.allclose(s.T_cam_target, SCENE.T_cam_target)
    assert s.ids[0] == "s0"
    _write_csv(path, rot, unit_scale=1000.0)
    s = load_pose_pairs(path, length_unit="mm")
    assert np.allclose(s.T_base_tcp, SCENE.T_base_tcp)


def test_csv_errors_are_explicit(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("base_tcp_x,base_tcp_y,base_tcp_z\n1,2,3\n")
    with pytest.raises(HandEyeInputError, match="missing columns"):
        load_pose_pairs(path)
    _write_csv(path, "quat")
    text = path.read_text().splitlines()
    header, first = text[1].split(","), text[2].split(",")
    first[header.index("base_tcp_qw")] = "2.0"  # not a unit quaternion: columns mixed up?
    path.write_text("\n".join([text[1], ",".join(first)]) + "\n")
    with pytest.raises(HandEyeInputError, match="norm"):
        load_pose_pairs(path)
    _write_csv(path, "rotvec")
    text = path.read_text().splitlines()
    header, first = text[1].split(","), text[2].split(",")
    first[header.index("cam_target_rx")] = "90.0"  # degrees
    path.write_text("\n".join([text[1], ",".join(first)]) + "\n")
    with pytest.raises(HandEyeInputError, match="degrees"):
        load_pose_pairs(path)
    with pytest.raises(HandEyeInputError, match="unsupported"):
        load_pose_pairs(tmp_path / "x.yaml")
