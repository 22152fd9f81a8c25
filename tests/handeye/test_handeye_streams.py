"""Hand-eye from two streams with their own clocks (plugins/calibration/handeye/streams.py): the
robot at 125 Hz, the camera at 30 Hz with 0.5 ms stamp jitter and 0.5 mm / 0.05 deg noise, the
camera's clock behind by 0 to 200 ms; the robot moving continuously (six sinusoids). The offset
comes out within 1 ms with its 1-sigma; interpolation never reaches across a gap."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_rotvec, inv
from plugins.calibration.handeye.streams import PoseStream, coarse_offset, fit_offset, interpolate, paired

X = T_from_rotvec([0.1, -0.2, 0.05], [0.03, -0.01, 0.08])  # T_tcp_cam
Y = T_from_rotvec([np.pi, 0.0, 0.0], [0.6, 0.1, 0.0])  # T_base_target
T0 = T_from_rotvec([np.pi, 0.0, 0.0], [0.6, 0.1, 0.45])


def poses(rotvecs: np.ndarray, translations: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(rotvecs), 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rotvecs).as_matrix()
    T[:, :3, 3] = translations
    return T


def streams(
    offset_s: float, seed: int = 3, *, stamp_error_s: float = 0.0, noise_deg: float = 0.05, noise_m: float = 5e-4
) -> tuple[PoseStream, PoseStream]:
    """The robot's and the camera's stream; the camera's frames at irregular times (0.5 ms sd), each
    stamped with its time plus an error of *stamp_error_s* sd (the pose is the true one's)."""
    rng = np.random.default_rng(seed)
    freq, phase = rng.uniform(0.05, 0.3, 6), rng.uniform(0, 2 * np.pi, 6)
    amp = np.array([0.35, 0.35, 0.5, 0.08, 0.08, 0.06])

    def flange(t: np.ndarray) -> np.ndarray:
        w = amp * np.sin(2 * np.pi * freq * t[:, None] + phase)
        return T0 @ poses(w[:, :3], w[:, 3:])

    t_robot = np.arange(0.0, 60.0, 1 / 125)
    t_seen = np.arange(1.0, 59.0, 1 / 30) + rng.normal(0, 5e-4, len(np.arange(1.0, 59.0, 1 / 30)))
    B = inv(X) @ inv(flange(t_seen)) @ Y
    noise = poses(rng.normal(0, np.radians(noise_deg), (len(B), 3)), rng.normal(0, noise_m, (len(B), 3)))
    stamps = t_seen + (rng.normal(0, stamp_error_s, len(t_seen)) if stamp_error_s else 0.0)
    return PoseStream(t_robot, flange(t_robot)), PoseStream(stamps - offset_s, B @ noise)


@pytest.mark.parametrize("offset_ms", [0.0, 20.0, 100.0, -200.0])
def test_the_clock_offset_is_found_within_a_millisecond(offset_ms: float):
    robot, camera = streams(offset_ms / 1e3)
    fit = fit_offset("eye_in_hand", robot, camera)
    assert abs(fit.offset_s * 1e3 - offset_ms) < 1.0, fit
    assert 0.02 < fit.sigma_s * 1e3 < 1.0  # a 1-sigma of the right order: the error above is within 3 of it
    assert abs(fit.offset_s * 1e3 - offset_ms) < 3 * fit.sigma_s * 1e3 + 0.05
    assert abs(fit.coarse_s * 1e3 - offset_ms) < 10.0  # the cross-correlation's start, to its grid step
    assert fit.n_paired > 1700


def test_the_offset_sigma_is_honest_over_seeds():
    errors = []
    for seed in range(8):
        fit = fit_offset("eye_in_hand", *streams(0.05, seed))
        errors.append((fit.offset_s - 0.05) / fit.sigma_s)
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert 0.3 < rms < 2.5, errors  # normalised errors of unit spread (8 draws: loose bounds)


def test_the_offset_sigma_counts_stamp_jitter():
    """2 ms of stamp jitter, little pose noise: each sample's error grows with the motion's speed.
    The sandwich 1-sigma stays honest; the curvature alone (as if every sample were equally noisy)
    made the normalised errors' RMS 2.0 on these 12 sets (the sandwich: 0.83)."""
    errors = []
    for seed in range(12):
        fit = fit_offset("eye_in_hand", *streams(0.05, seed, stamp_error_s=2e-3, noise_deg=0.02, noise_m=2e-4))
        errors.append((fit.offset_s - 0.05) / fit.sigma_s)
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert 0.6 < rms < 1.5, errors


def test_interpolation_stays_inside_the_stream_and_off_its_gaps():
    robot, _ = streams(0.0)
    keep = np.ones(len(robot.stamps_s), bool)
    keep[1000:1010] = False  # 80 ms without a robot pose
    gappy = PoseStream(robot.stamps_s[keep], robot.T[keep])
    t = np.array([-1.0, 5.0, robot.stamps_s[1004], 61.0])
    T, ok = interpolate(gappy, t)
    assert ok.tolist() == [False, True, False, False] and np.isnan(T[~ok]).all()
    mid, ok_mid = interpolate(robot, np.array([robot.stamps_s[10] + 0.5 / 125]))
    assert ok_mid.all()
    halfway = Rotation.from_matrix(robot.T[10, :3, :3]).inv() * Rotation.from_matrix(mid[0, :3, :3])
    step = Rotation.from_matrix(robot.T[10, :3, :3]).inv() * Rotation.from_matrix(robot.T[11, :3, :3])
    assert halfway.magnitude() == pytest.approx(step.magnitude() / 2, rel=1e-6)


def test_streams_that_do_not_overlap_are_refused():
    robot, camera = streams(0.0)
    far = PoseStream(camera.stamps_s + 1000.0, camera.T)
    with pytest.raises(ValueError, match="do not overlap"):
        fit_offset("eye_in_hand", robot, far)
    assert coarse_offset(robot, camera, 0.3) == pytest.approx(0.0, abs=0.01)
    M, B, ok = paired(robot, camera, 0.0)
    assert len(M) == len(B) == ok.sum()


def write_streams(path, robot: PoseStream, camera: PoseStream, **top) -> None:
    import json

    doc = {
        "format": "vgr.handeye.streams/1",
        "length_unit": "m",
        **top,
        "robot": [
            {"stamp_s": float(t), "T_base_tcp": T.tolist()} for t, T in zip(robot.stamps_s, robot.T, strict=True)
        ],
        "camera": [
            {"stamp_s": float(t), "T_cam_target": T.tolist()} for t, T in zip(camera.stamps_s, camera.T, strict=True)
        ],
    }
    doc["camera"][5]["T_cam_target"] = None  # a frame without a detection
    path.write_text(json.dumps(doc))


def test_a_streams_file_calibrates_with_the_offset_estimated_and_said(tmp_path, capsys):
    import json

    from plugins.calibration.cli import main as calibrate_main

    robot, camera = streams(0.04)
    write_streams(tmp_path / "streams.json", robot, camera)  # no set-up: the chains tell it
    code = calibrate_main(["handeye", str(tmp_path / "streams.json"), "--json", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    assert code in (0, 3), out
    assert "1 camera frame(s) without a pose dropped" in out
    said = float(out.split("clock offset ")[1].split(" ")[0])
    assert abs(said - 40.0) < 1.0, out
    res = json.loads((tmp_path / "r.json").read_text())
    X_hat = np.asarray(res["estimate"]["T_tcp_cam"])
    assert np.linalg.norm(X_hat[:3, 3] - X[:3, 3]) < 1e-3  # (the set-up found: eye in hand)
    # the offset and its 1-sigma are numbers of the result, not only words
    m = res["metrics"]
    assert abs(m["clock_offset_s"] - 0.04) < 1e-3 and 0 < m["clock_offset_sd_s"] < 1e-3
    # a known offset is taken as the file says
    write_streams(tmp_path / "known.json", robot, camera, setup="eye_in_hand", clock_offset_s=0.04)
    assert calibrate_main(["handeye", str(tmp_path / "known.json")]) in (0, 3)
    assert "clock offset 40.000 ms (robot - camera), as the file says" in capsys.readouterr().out


def test_two_streams_in_memory_pair_as_a_file_does():
    from plugins.calibration.handeye.stream_file import pair_streams

    robot, camera = streams(0.02)
    samples = pair_streams(robot, camera, setup="eye_in_hand")
    assert abs(samples.metrics["clock_offset_s"] - 0.02) < 1e-3 and samples.setup == "eye_in_hand"
    assert len(samples.T_base_tcp) == len(samples.ids) <= 200
    known = pair_streams(robot, camera, setup="eye_in_hand", clock_offset_s=0.02)
    assert known.metrics == {"clock_offset_s": 0.02} and "as given" in known.notes[0]
