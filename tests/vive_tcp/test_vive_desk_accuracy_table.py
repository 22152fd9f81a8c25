"""Seed 001's accuracy claims checked against simulation (mm, deg; fixed seeds).

The full table (3/4/5 points x 0/0.5/1/2/5 deg scatter, 50 trials per cell) is in
benchmarks/vive_desk.py and docs/vive_and_tcp.md; this test keeps a small, fast subset."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from engine.transforms import T_from_Rt, inv
from plugins.calibration.vive_desk import calibrate_vive_desk
from plugins.calibration.vive_desk.realtime import desktop_tcp, desktop_tcp_jacobians
from plugins.calibration.vive_desk.seed_baseline import seed_calibrate
from plugins.calibration.vive_desk.simulate import (
    SEED_POINTS_3,
    SEED_POINTS_4,
    SEED_POINTS_5,
    simulate_contacts,
    tilted_fixture_orientations,
)
from plugins.calibration.vive_desk.solver import cramer_rao_bound


def pairwise_to_sigma(deg):
    return np.radians(deg) / np.sqrt(6.0)  # per-axis sigma whose RMS pairwise difference is deg


def tcp_errors(T_BD, T_KC, sim):
    """(error at the calibration orientation, errors 20 deg away about desk x/y/z), position, m."""

    def err(T_BK):
        a = desktop_tcp(T_BK, T_BD, T_KC)
        b = desktop_tcp(T_BK, sim.T_base_desktop, sim.T_tracker_tcp)
        return np.linalg.norm(a[:3, 3] - b[:3, 3])

    tilted = []
    for axis in "xyz":
        R = Rotation.from_euler(axis, 20, degrees=True).as_matrix()
        tilted.append(err(sim.T_base_desktop @ T_from_Rt(R, [0.1, -0.1, 0.12]) @ inv(sim.T_tracker_tcp)))
    return err(sim.T_base_tracker_true[0]), tilted


def test_more_points_lower_the_bound_as_the_seed_says():
    """CRLB of the TCP position at the calibration orientation (deterministic): 4 points about
    10 % below 3, 5 points about 15 % below 3 (the seed estimates 15-20 % and 20-30 %)."""
    bounds = []
    for P in (SEED_POINTS_3, SEED_POINTS_4, SEED_POINTS_5):
        sim = simulate_contacts(P, seed=0, fixture_scatter_rad=pairwise_to_sigma(0.5))
        crlb, _ = cramer_rao_bound(sim.data, sim.T_base_desktop, sim.T_tracker_tcp)
        Jc, _ = desktop_tcp_jacobians(sim.T_base_tracker_true[0], sim.T_base_desktop, sim.T_tracker_tcp)
        bounds.append(np.sqrt(np.trace((Jc @ crlb @ Jc.T)[:3, :3])))
    b3, b4, b5 = bounds
    assert 0.6e-3 < b3 < 0.85e-3  # sub-millimetre with 0.5 mm Vive jitter: the seed's "< 1 mm"
    assert 0.05 < 1 - b4 / b3 < 0.2 and 0.1 < 1 - b5 / b3 < 0.3


@pytest.mark.slow
@pytest.mark.parametrize("scatter_deg", [0.5, 2.0])
def test_seed_table_subset(scatter_deg):
    """20 trials, 3 points. Single orientation: vgr's TCP error at the calibration orientation stays
    near 1 mm even at 2 deg scatter (the seed predicts L x angle = 5.2 mm; modelling the scatter as
    a rotation about the TCP removes most of it) and is no worse than the seed's L-BFGS-B; 20 deg
    away from the calibration orientation both are off by centimetres (lever arm unidentifiable).
    Three fixture orientations bring the 20 deg error to ~1 mm."""
    cal = {"vgr": [], "seed": [], "vgr3": []}
    tilt = {"vgr": [], "seed": [], "vgr3": []}
    R3 = tilted_fixture_orientations()
    for k in range(20):
        kw = dict(fixture_scatter_rad=pairwise_to_sigma(scatter_deg))
        sim = simulate_contacts(SEED_POINTS_3, seed=500 + k, **kw)
        sim3 = simulate_contacts(
            np.vstack([SEED_POINTS_3] * 3), seed=500 + k, R_desktop_tcp=np.repeat(R3, 3, axis=0), **kw
        )
        res = calibrate_vive_desk(sim.data)
        sr = seed_calibrate(sim.data)
        res3 = calibrate_vive_desk(sim3.data)
        for m, (A, B, s) in {
            "vgr": (res.estimate["T_base_desktop"], res.estimate["T_tracker_tcp"], sim),
            "seed": (sr.T_base_desktop, sr.T_tracker_tcp, sim),
            "vgr3": (res3.estimate["T_base_desktop"], res3.estimate["T_tracker_tcp"], sim3),
        }.items():
            c, t = tcp_errors(A, B, s)
            cal[m].append(c)
            tilt[m] += t
    rms = {m: np.sqrt(np.mean(np.square(v))) * 1e3 for m, v in cal.items()}
    rms_tilt = {m: np.sqrt(np.mean(np.square(v))) * 1e3 for m, v in tilt.items()}
    print(f"scatter {scatter_deg} deg: at calibration {rms} mm; 20 deg away {rms_tilt} mm")
    assert rms["vgr"] < 1.3 and rms["vgr"] <= 1.1 * rms["seed"]
    assert rms_tilt["vgr"] > 5.0 and rms_tilt["seed"] > 5.0
    assert rms_tilt["vgr3"] < 1.5 and rms["vgr3"] < 1.0
