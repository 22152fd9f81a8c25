"""Per-sample camera covariances in the pose files (plugins/calibration/handeye/covariance_file.py):
``camera_cov`` (36 numbers, row-major) or ``camera_sigma`` (6) in the vgr JSON, the CSV columns
``camera_cov_RC`` / ``camera_sigma_*``, OpenCV YAML's ``camera_cov_<i>`` / ``camera_sigma_<i>`` and a
stream file's camera entries; round trips, the length unit, refusals naming the sample."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from engine.transforms import T_from_rotvec, inv
from plugins.calibration.handeye import HandEyeInputError, NoiseModel, calibrate_hand_eye
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.covariance_file import CSV_COV_COLUMNS, CSV_SIGMA_COLUMNS
from plugins.calibration.handeye.io import VGR_FORMAT, load_pose_pairs, write_pose_pairs_json, write_pose_pairs_yaml
from plugins.calibration.handeye.stream_file import load_samples

RNG = np.random.default_rng(60)
SCENE = sim.viewing_scene(RNG, 6, "eye_in_hand")
COV = sim.depth_covariances(SCENE.T_cam_target, RNG)  # full, correlated
SIGMA = np.sqrt(np.diagonal(COV, axis1=1, axis2=2))
MM = np.array([1e3] * 3 + [1.0] * 3)  # metres -> millimetres for (tx, ty, tz, rx, ry, rz)


def _pose_cells(T: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    return [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_rotvec()]


def _write_csv(path: Path, columns: tuple[str, ...], values: np.ndarray, scale: float = 1.0) -> None:
    head = ["id"] + [f"{p}_{c}" for p in ("base_tcp", "cam_target") for c in ("x", "y", "z", "rx", "ry", "rz")]
    lines = [",".join([*head, *columns])]
    for k in range(6):
        cells = _pose_cells(SCENE.T_base_tcp[k]) + _pose_cells(SCENE.T_cam_target[k])
        for j in (0, 1, 2, 6, 7, 8):
            cells[j] *= scale
        lines.append(",".join([f"s{k}", *(repr(float(v)) for v in cells), *(repr(float(v)) for v in values[k])]))
    path.write_text("\n".join(lines) + "\n")


def test_vgr_json_round_trip_with_covariances_and_sigmas_in_mm(tmp_path):
    path = tmp_path / "s.json"
    write_pose_pairs_json(path, SCENE.T_base_tcp, SCENE.T_cam_target, camera_covariances=COV)
    s = load_pose_pairs(path)
    assert s.camera_covariances is not None and np.array_equal(s.camera_covariances, COV)
    assert len(json.loads(path.read_text())["samples"][0]["camera_cov"]) == 36
    # camera_sigma in a millimetre file: metres and a diagonal covariance
    doc = json.loads(path.read_text())
    doc["length_unit"] = "mm"
    for k, smp in enumerate(doc["samples"]):
        for key in ("T_base_tcp", "T_cam_target"):
            T = np.asarray(smp[key])
            T[:3, 3] *= 1e3
            smp[key] = T.tolist()
        del smp["camera_cov"]
        smp["camera_sigma"] = (SIGMA[k] * MM).tolist()
    path.write_text(json.dumps(doc))
    s = load_pose_pairs(path)
    assert np.allclose(s.camera_covariances, np.stack([np.diag(v**2) for v in SIGMA]), rtol=1e-12, atol=0)
    assert np.allclose(s.T_cam_target, SCENE.T_cam_target)
    # the solver takes them as they come
    res = calibrate_hand_eye(s.T_base_tcp, s.T_cam_target, setup="eye_in_hand", camera_covariances=s.camera_covariances)
    assert res.metrics["camera_covariances_given"] == 1.0


@pytest.mark.parametrize("kind", ["cov", "sigma"])
def test_csv_covariance_columns_round_trip_in_m_and_mm(tmp_path, kind):
    path = tmp_path / "s.csv"
    cols, values = (CSV_COV_COLUMNS, COV.reshape(6, 36)) if kind == "cov" else (CSV_SIGMA_COLUMNS, SIGMA)
    expected = COV if kind == "cov" else np.stack([np.diag(v**2) for v in SIGMA])
    _write_csv(path, cols, values)
    s = load_pose_pairs(path)
    assert np.allclose(s.camera_covariances, expected, rtol=1e-12, atol=0) and s.ids[0] == "s0"
    mm_values = (COV * MM[:, None] * MM[None, :]).reshape(6, 36) if kind == "cov" else SIGMA * MM
    _write_csv(path, cols, mm_values, scale=1e3)
    s = load_pose_pairs(path, length_unit="mm")
    assert np.allclose(s.camera_covariances, expected, rtol=1e-12, atol=0)


def test_opencv_yaml_round_trip_with_covariances_and_sigmas(tmp_path):
    path = tmp_path / "pairs.yml"
    write_pose_pairs_yaml(path, SCENE.T_base_tcp, SCENE.T_cam_target, camera_covariances=COV)
    s = load_pose_pairs(path)
    assert np.allclose(s.camera_covariances, COV, rtol=1e-12, atol=0)
    text = path.read_text()
    for k in range(6):  # the same file with each sample's sigmas instead (a 6x1 opencv-matrix)
        start = text.index(f"camera_cov_{k}:")
        end = text.index("]", start) + 1
        data = ", ".join(repr(float(v)) for v in SIGMA[k])
        block = f"camera_sigma_{k}: !!opencv-matrix\n   rows: 6\n   cols: 1\n   dt: d\n   data: [ {data} ]"
        text = text[:start] + block + text[end:]
    path.write_text(text)
    s = load_pose_pairs(path)
    assert np.allclose(s.camera_covariances, np.stack([np.diag(v**2) for v in SIGMA]), rtol=1e-12, atol=0)


def _streams_doc(with_cov: bool = True) -> dict:
    X = T_from_rotvec([0.1, -0.2, 0.05], [0.03, -0.01, 0.08])
    Y = T_from_rotvec([np.pi, 0.0, 0.0], [0.6, 0.1, 0.0])
    t_robot = np.arange(0.0, 10.0, 1 / 100)
    t_cam = np.arange(1.0, 9.0, 1 / 10)

    def flange(t: np.ndarray) -> np.ndarray:
        w = 0.3 * np.sin(np.outer(t, [0.3, 0.5, 0.7, 0.2, 0.4, 0.6]))
        return np.stack(
            [
                Y @ T_from_rotvec(r, np.array([0.0, 0.0, 0.45]) + p)
                for r, p in zip(w[:, :3], w[:, 3:] * 0.2, strict=True)
            ]
        )

    B = inv(X) @ inv(flange(t_cam)) @ Y
    cov = sim.depth_covariances(B, np.random.default_rng(61))
    camera = [{"stamp_s": float(t), "T_cam_target": b.tolist()} for t, b in zip(t_cam, B, strict=True)]
    if with_cov:
        for e, c in zip(camera, cov, strict=True):
            e["camera_cov"] = c.reshape(36).tolist()
    robot = [{"stamp_s": float(t), "T_base_tcp": m.tolist()} for t, m in zip(t_robot, flange(t_robot), strict=True)]
    camera[4]["T_cam_target"] = None  # a frame without a detection: dropped with its covariance
    return {"format": "vgr.handeye.streams/1", "setup": "eye_in_hand", "clock_offset_s": 0.0, "robot": robot,
            "camera": camera, "_cov": cov}  # fmt: skip


def test_a_stream_files_camera_entries_keep_their_covariances(tmp_path):
    doc = _streams_doc()
    cov = doc.pop("_cov")
    path = tmp_path / "streams.json"
    path.write_text(json.dumps(doc))
    s = load_samples(path)
    keep = [k for k in range(len(cov)) if k != 4]
    assert s.camera_covariances is not None and len(s.camera_covariances) == len(s.T_cam_target) == len(keep)
    assert np.allclose(s.camera_covariances, cov[keep], rtol=1e-12, atol=0)
    doc["camera"][7]["camera_cov"] = doc["camera"][7]["camera_cov"][:35]
    path.write_text(json.dumps(doc))
    with pytest.raises(HandEyeInputError, match=r"entry 7.*camera_cov.*36 numbers, got 35"):
        load_samples(path)


def test_bad_covariances_in_files_are_refused_naming_the_sample(tmp_path):
    path = tmp_path / "s.json"
    write_pose_pairs_json(path, SCENE.T_base_tcp, SCENE.T_cam_target, ids=[f"p{k}" for k in range(6)],
                          camera_covariances=COV)  # fmt: skip
    good = json.loads(path.read_text())

    def refused(edit, message: str) -> None:
        doc = json.loads(json.dumps(good))
        edit(doc["samples"][3])
        path.write_text(json.dumps(doc))
        with pytest.raises(HandEyeInputError, match=message):
            load_pose_pairs(path)

    refused(lambda smp: smp.update(camera_cov=smp["camera_cov"][:30]), "sample p3.*36 numbers, got 30")
    refused(lambda smp: smp.update(camera_sigma=[1e-3] * 6), "sample p3.*camera_cov or camera_sigma, not both")
    refused(lambda smp: smp.update(camera_cov=None, camera_sigma=[1e-3] * 5), "sample p3.*6 numbers, got 5")
    refused(lambda smp: smp.pop("camera_cov"), "some samples but not for p3")
    refused(lambda smp: smp.update(camera_cov=(-np.eye(6)).reshape(36).tolist()), "p3.*not positive definite")
    asym = COV[3].copy()
    asym[0, 5] += 0.5 * np.sqrt(asym[0, 0] * asym[5, 5])
    refused(lambda smp: smp.update(camera_cov=asym.reshape(36).tolist()), "p3.*not symmetric")
    # CSV: a partial set of columns, a partly empty row
    csv = tmp_path / "s.csv"
    _write_csv(csv, CSV_SIGMA_COLUMNS[:5], SIGMA[:, :5])
    with pytest.raises(HandEyeInputError, match=r"camera_sigma_.*incomplete.*camera_sigma_rz"):
        load_pose_pairs(csv)
    _write_csv(csv, CSV_SIGMA_COLUMNS, SIGMA)
    lines = csv.read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ","
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(HandEyeInputError, match=r"sample s2: camera_sigma_.*partly empty"):
        load_pose_pairs(csv)
    # YAML: a covariance that is not 6x6
    yml = tmp_path / "p.yml"
    write_pose_pairs_yaml(yml, SCENE.T_base_tcp, SCENE.T_cam_target, camera_covariances=COV)
    text = yml.read_text()
    start = text.index("camera_cov_2:")
    end = text.index("]", start) + 1
    yml.write_text(text[:start] + "camera_cov_2: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                   "   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]" + text[end:])  # fmt: skip
    with pytest.raises(HandEyeInputError, match=r"sample 2.*36 numbers, got 9"):
        load_pose_pairs(yml)


def test_files_without_covariances_load_as_before(tmp_path):
    path = tmp_path / "s.json"
    write_pose_pairs_json(path, SCENE.T_base_tcp, SCENE.T_cam_target)
    assert load_pose_pairs(path).camera_covariances is None
    doc = {"format": VGR_FORMAT, "samples": json.loads(path.read_text())["samples"]}
    path.write_text(json.dumps(doc))
    assert load_pose_pairs(path).camera_covariances is None
    stream = tmp_path / "streams.json"
    doc = _streams_doc(with_cov=False)
    doc.pop("_cov")
    stream.write_text(json.dumps(doc))
    assert load_samples(stream).camera_covariances is None


def test_vgr_calibrate_passes_a_files_covariances_unless_the_camera_noise_is_declared(tmp_path, capsys):
    from plugins.calibration.cli import main as calibrate_main

    rng = np.random.default_rng(62)
    scene = sim.viewing_scene(rng, 15)
    C = sim.depth_covariances(scene.T_cam_target, rng)
    meas = sim.add_noise(scene, NoiseModel.isotropic(0.01, 0.1, 0.1, 0.5), rng)
    B = sim.perturb_poses_cov(scene.T_cam_target, C, rng)
    path = tmp_path / "s.json"
    write_pose_pairs_json(path, meas.T_base_tcp, B, setup="eye_in_hand", camera_covariances=C)
    out = tmp_path / "r.json"
    assert calibrate_main(["handeye", str(path), "--json", str(out)]) in (0, 3)
    assert json.loads(out.read_text())["metrics"]["camera_covariances_given"] == 1.0
    assert "median of per-sample covariances" in capsys.readouterr().out
    assert calibrate_main(["handeye", str(path), "--camera-noise", "0.1", "2", "--json", str(out)]) in (0, 3)
    assert "camera_covariances_given" not in json.loads(out.read_text())["metrics"]
    assert "covariances of the data are not used" in capsys.readouterr().out
