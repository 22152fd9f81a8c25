"""Plain-file loaders: MoveIt JSON, vgr JSON, CSV (quaternion or rotation-vector columns, m or mm) and
OpenCV FileStorage YAML in camodocal's layout; the sample ids each format carries."""

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from shared_data import SHARED

from plugins.calibration.handeye import HandEyeInputError
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.io import VGR_FORMAT, load_pose_pairs, write_pose_pairs_json, write_pose_pairs_yaml

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
        load_pose_pairs(tmp_path / "x.txt")


# --------------------------------------------------------------------------- CSV sample ids


def test_csv_without_an_id_column_names_samples_by_their_line(tmp_path):
    path = tmp_path / "s.csv"
    _write_csv(path, "quat")
    lines = path.read_text().splitlines()
    lines = [ln.split(",", 1)[1] if not ln.startswith("#") else ln for ln in lines]  # drop the id column
    lines.insert(3, "# a comment between samples")
    path.write_text("\n".join(lines) + "\n")
    s = load_pose_pairs(path)
    # line 1 comment, line 2 header, samples on lines 3, 5, 6, ... (line 4 is the inserted comment)
    assert s.ids == ["line 3", "line 5", "line 6", "line 7", "line 8", "line 9"]
    assert np.allclose(s.T_base_tcp, SCENE.T_base_tcp)


# --------------------------------------------------------------------------- OpenCV YAML (camodocal)


def _matrix(key: str, A: np.ndarray) -> str:
    """One !!opencv-matrix entry laid out as OpenCV writes it (data wrapped over lines)."""
    vals = [repr(float(v)) for v in np.asarray(A, dtype=float).ravel()]
    rows, cols = np.asarray(A).shape if np.ndim(A) == 2 else (1, len(vals))
    data = ",\n       ".join(", ".join(vals[k : k + 3]) for k in range(0, len(vals), 3))
    return f"{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n"


def _camodocal_yaml(M: np.ndarray, B: np.ndarray, order: list[int], frame_count: int | None = None) -> str:
    text = "%YAML:1.0\n" + (f"frameCount: {len(order) if frame_count is None else frame_count}\n")
    for i in order:
        text += _matrix(f"T1_{i}", M[i]) + _matrix(f"T2_{i}", B[i])
    return text


def test_opencv_yaml_round_trip(tmp_path):
    path = tmp_path / "TransformPairsInput.yml"
    write_pose_pairs_yaml(path, SCENE.T_base_tcp, SCENE.T_cam_target)
    text = path.read_text()
    assert text.startswith("%YAML:1.0") and "frameCount: 6" in text and "T2_5: !!opencv-matrix" in text
    s = load_pose_pairs(path)
    assert np.allclose(s.T_base_tcp, SCENE.T_base_tcp, rtol=0, atol=1e-15)
    assert np.allclose(s.T_cam_target, SCENE.T_cam_target, rtol=0, atol=1e-15)
    assert s.ids == [str(i) for i in range(6)] and s.setup is None
    mm = load_pose_pairs(path, length_unit="mm")
    assert np.allclose(mm.T_base_tcp[:, :3, 3], SCENE.T_base_tcp[:, :3, 3] / 1000)


def test_camodocal_layout_is_read_in_sample_order_with_its_ids(tmp_path):
    """Keys as camodocal's ROS wrapper writes them, here with ids out of order and not from 0."""
    M, B = SCENE.T_base_tcp, SCENE.T_cam_target
    path = tmp_path / "pairs.yaml"
    path.write_text(_camodocal_yaml(M, B, [5, 1, 4, 2, 3]))  # sample 0 deleted from the file
    s = load_pose_pairs(path)
    assert s.ids == ["1", "2", "3", "4", "5"]
    assert np.allclose(s.T_base_tcp, M[1:]) and np.allclose(s.T_cam_target, B[1:])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("frameCount: 1\n", "must start with %YAML:1.0"),
        ("%YAML:1.0\nframeCount: 0\n", r"no T1_<i> / T2_<i> matrices"),
        ("%YAML:1.0\nT1_0: [1, 2\n", "OpenCV cannot parse"),
        ("%YAML:1.0\nT1_0: 5\nT2_0: 6\n", "T1_0 is not an opencv-matrix"),
    ],
)
def test_opencv_yaml_errors_say_what_is_wrong(tmp_path, text, message):
    path = tmp_path / "bad.yml"
    path.write_text(text)
    with pytest.raises(HandEyeInputError, match=message):
        load_pose_pairs(path)


def test_opencv_yaml_layout_errors_name_the_sample(tmp_path):
    M, B = SCENE.T_base_tcp, SCENE.T_cam_target
    path = tmp_path / "bad.yml"
    path.write_text(_camodocal_yaml(M, B, [0, 1, 2], frame_count=4))
    with pytest.raises(HandEyeInputError, match="frameCount says 4 but the file holds 3"):
        load_pose_pairs(path)
    path.write_text(_camodocal_yaml(M, B, [0, 1]) + _matrix("T1_2", M[2]))
    with pytest.raises(HandEyeInputError, match="T1_2 has no T2_2"):
        load_pose_pairs(path)
    path.write_text(_camodocal_yaml(M, B, [0], frame_count=2) + _matrix("T1_1", M[1]) + _matrix("T2_1", B[1][:3, :3]))
    with pytest.raises(HandEyeInputError, match="T2_1 is 3x3, not 4x4"):
        load_pose_pairs(path)
    path.write_text(_camodocal_yaml(M, B, [0, 1]).replace("rows: 4", "rows: 5", 1))
    with pytest.raises(HandEyeInputError, match="T1_0 is a malformed opencv-matrix"):
        load_pose_pairs(path)


_KEYS = st.sampled_from(["frameCount", "T1_0", "T2_0", "T1_1", "T2_1", "T1_x", "T2_x", "other"])
_SCALARS = st.one_of(st.integers(-5, 5).map(str), st.floats(allow_nan=True).map(repr), st.sampled_from(["abc", "[]"]))


@st.composite
def _garbled_yaml(draw) -> bytes:
    """Anything from bytes to nearly valid FileStorage documents with wrong keys, shapes and values."""
    kind = draw(st.integers(0, 2))
    if kind == 0:
        return draw(st.binary(max_size=200))
    if kind == 1:
        return ("%YAML:1.0\n" + draw(st.text(max_size=200))).encode("utf-8", "surrogatepass")
    text = "%YAML:1.0\n"
    for _ in range(draw(st.integers(0, 6))):
        key = draw(_KEYS)
        if draw(st.booleans()):
            rows, cols = draw(st.integers(1, 5)), draw(st.integers(1, 5))
            n = rows * cols + draw(st.sampled_from([0, 0, 0, -1, 1]))
            vals = draw(st.lists(st.floats(-2, 2), min_size=max(n, 0), max_size=max(n, 0)))
            text += f"{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {', '.join(map(repr, vals))} ]\n"
        else:
            text += f"{key}: {draw(_SCALARS)}\n"
    return text.encode()


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(_garbled_yaml())
def test_garbage_yaml_is_a_clear_error_never_a_crash(tmp_path, content):
    path = tmp_path / "garbage.yml"
    path.write_bytes(content)
    try:
        s = load_pose_pairs(path)
    except HandEyeInputError as exc:
        assert str(path) in str(exc)
    else:  # what it read is a consistent set of 4x4 pose pairs with one id each
        assert s.T_base_tcp.shape == s.T_cam_target.shape == (len(s.ids), 4, 4)
