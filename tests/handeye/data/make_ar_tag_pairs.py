"""Writes ar_tag_pairs.yml: a small, realistic AR-tag hand-eye data set in camodocal's layout.

What it imitates: a fixed camera watching an AR tag held by the robot (eye to hand), recorded the
way the ROS wrapper of camodocal records it (``TransformPairsInput.yml``: ``T1_i`` the robot pose
base -> end effector, ``T2_i`` the camera -> tag pose, OpenCV FileStorage YAML, metres). Single-tag
poses are noisy: 1.5 deg about the image axes and 1.2 deg about the viewing axis, 1 mm across and
3 mm along the line of sight (1 sigma); the robot reports its pose to 0.01 deg / 0.1 mm. One
detection (pair 13) is a gross outlier: the tag's pose flipped by 25 deg, as single-tag
detections sometimes do. 20 pairs, seed 16.

Run ``python tests/handeye/data/make_ar_tag_pairs.py`` to rewrite the file; a test checks that
the committed file is what this script makes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from engine.transforms import retract  # noqa: E402
from plugins.calibration.handeye import NoiseModel, PoseNoise  # noqa: E402
from plugins.calibration.handeye import simulate as sim  # noqa: E402
from plugins.calibration.handeye.io import write_pose_pairs_yaml  # noqa: E402

HERE = Path(__file__).resolve().parent
FILE = HERE / "ar_tag_pairs.yml"
SEED = 16
N_PAIRS = 20
OUTLIER = 13
NOISE = NoiseModel(
    robot=PoseNoise.from_deg_mm(0.01, 0.1),
    camera=PoseNoise.from_deg_mm((1.5, 1.5, 1.2), (1.0, 1.0, 3.0)),
)


def make() -> sim.Scene:
    """The measured samples (and the truth) of the data set."""
    rng = np.random.default_rng(SEED)
    truth = sim.viewing_scene(rng, N_PAIRS, "eye_to_hand")
    meas = sim.add_noise(truth, NOISE, rng)
    B = meas.T_cam_target.copy()
    B[OUTLIER] = retract(B[OUTLIER : OUTLIER + 1], np.array([[0.0, 0.0, 0.0, np.deg2rad(25.0), 0.0, 0.0]]))[0]
    return sim.Scene(meas.setup, meas.T_base_tcp, B, truth.X, truth.Y)


def main(path: Path = FILE) -> Path:
    scene = make()
    write_pose_pairs_yaml(path, scene.T_base_tcp, scene.T_cam_target)
    return path


if __name__ == "__main__":
    print(main())
