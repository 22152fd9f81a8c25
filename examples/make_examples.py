"""Write the sample data files in examples/ (simulated, seeds fixed), one per `vgr calibrate` kind
and one campaign for `vgr gap`, so each command in examples/README.md runs as written.

    python examples/make_examples.py      # rewrites the files; tests/test_examples.py checks they
                                          # are what this script writes and that each command runs

The files are in the plain formats of docs/calibration.md and docs/model_gap.md; the truth each
was simulated from is in examples/README.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from plugins.calibration.handeye.io import write_pose_pairs_json  # noqa: E402
from plugins.calibration.handeye.noise import NoiseModel  # noqa: E402
from plugins.calibration.handeye.simulate import add_noise, viewing_scene  # noqa: E402
from plugins.calibration.tcp_camera.io import save_tcp_csv  # noqa: E402
from plugins.calibration.tcp_camera.simulate import simulate_tcp_camera  # noqa: E402
from plugins.calibration.vive_desk.io import save_vive_csv  # noqa: E402
from plugins.calibration.vive_desk.simulate import simulate_contacts, tilted_fixture_orientations  # noqa: E402
from plugins.model_gap.data import write_gap_csv  # noqa: E402
from plugins.sim.model_gap.simulate import LEVELS, HiddenCase, HiddenEffect, make_case  # noqa: E402

DESK_POINTS = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.3, 0.0], [0.3, 0.3, 0.0]])  # m, desk frame
FILES = ("handeye_eye_in_hand.json", "tcp_camera.csv", "vive_desk.csv", "ur5e_campaign.csv")


def write_all(out: Path = HERE) -> list[Path]:
    """Write every sample file into *out*; returns their paths (in :data:`FILES` order)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in FILES]
    # hand-eye, camera on the flange: 25 views of a target, robot 0.02 deg / 0.1 mm, camera 0.05 deg / 0.2 mm
    rng = np.random.default_rng(1)
    scene = add_noise(
        viewing_scene(rng, 25, "eye_in_hand", max_tilt_deg=45.0), NoiseModel.isotropic(0.02, 0.1, 0.05, 0.2), rng
    )
    write_pose_pairs_json(paths[0], scene.T_base_tcp, scene.T_cam_target, setup="eye_in_hand")
    # TCP with a fixed camera: 6 pure translations and 10 re-orientations, camera 0.3 mm per axis
    save_tcp_csv(simulate_tcp_camera(seed=2).data, paths[1])
    # Vive desk: four desk points touched with the fixture upright and tilted 30 deg about desk x and y
    # (the three orientations make the tracker-to-TCP lever arm identifiable), tracker 0.5 mm / 0.1 deg,
    # the tool seated within 0.05 deg
    points = np.vstack([DESK_POINTS] * 3)
    fixture = np.repeat(tilted_fixture_orientations(), len(DESK_POINTS), axis=0)
    sim = simulate_contacts(points, seed=3, R_desktop_tcp=fixture, fixture_scatter_rad=float(np.radians(0.05)))
    save_vive_csv(sim.data, paths[2])
    # a UR5e campaign of 200 tool points measured by a tracker (0.05 mm), with a hidden joint-2
    # compliance: input of both `vgr calibrate kinematics` and `vgr gap`
    hidden = (HiddenEffect("joint_compliance", "joint2", LEVELS["high"]),)
    case = HiddenCase("joint_compliance@joint2", "single", "high", "tracker", hidden, seed=4)
    write_gap_csv(make_case(case).data, paths[3])
    return paths


if __name__ == "__main__":
    for p in write_all():
        print(p.relative_to(HERE.parent))
