"""The outlier test on heavy-tailed noise (plugins/calibration/handeye/tails.py): a t tail of the
samples' costs moves Pope's bound out; Gaussian costs and gross outliers do not."""

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from engine.transforms import retract
from plugins.calibration.handeye import PoseNoise, calibrate_hand_eye
from plugins.calibration.handeye import simulate as sim
from plugins.calibration.handeye.tails import TAIL_FIT_RANGE, fit_tail

T0 = 6.0 * float(stats.f.ppf(0.999, 6, 200))  # Pope's bound at 0.999 with 200 redundant residuals


def test_gaussian_costs_keep_popes_bound():
    rng = np.random.default_rng(3)
    kept = [fit_tail(rng.chisquare(6, 40), T0, 0.999) for _ in range(50)]
    assert sum(f.heavy for f in kept) <= 3  # a 1 % test: 0.5 expected in 50 sets
    assert all(f.threshold == T0 for f in kept if not f.heavy)


def test_t_costs_move_the_bound_out_but_not_beyond_the_fitted_range():
    rng = np.random.default_rng(4)
    y = 6.0 * rng.f(6, 4, 400) * 0.5  # multivariate t, 4 dof, unit covariance
    fit = fit_tail(y, T0, 0.999)
    assert fit.heavy and 2.5 <= fit.nu <= 8.0
    assert T0 < fit.threshold <= TAIL_FIT_RANGE * T0


def test_gross_outliers_beyond_the_fitted_range_do_not_make_a_tail():
    rng = np.random.default_rng(5)
    y = np.concatenate([rng.chisquare(6, 20), rng.uniform(100.0, 1e5, 20)])  # 50 % gross outliers
    fit = fit_tail(y, T0, 0.999)
    assert not fit.heavy and fit.threshold == T0


def _t3(T: np.ndarray, noise: PoseNoise, rng: np.random.Generator) -> np.ndarray:
    """Poses with Student-t (3 dof) noise per coordinate, scaled to the sigmas' sd."""
    return retract(T, rng.standard_t(3.0, size=(len(T), 6)) / np.sqrt(3.0) * noise.sigmas6())


def test_heavy_tailed_noise_keeps_good_samples_and_flags_gross_errors():
    robot, camera = PoseNoise.from_deg_mm(0.01, 0.1), PoseNoise.from_deg_mm(0.1, 0.5)
    false_flags, good, missed, tails = 0, 0, 0, 0
    for seed in range(10):
        rng = np.random.default_rng([7, seed])
        scene = sim.viewing_scene(rng, 40, "eye_in_hand")
        M, B = _t3(scene.T_base_tcp, robot, rng), _t3(scene.T_cam_target, camera, rng)
        bad = np.zeros(40, bool)
        bad[rng.choice(40, 6, replace=False)] = True  # gross errors: 2-10 mm and 1-5 deg
        dt = Rotation.random(6, rng=rng).apply([1.0, 0, 0]) * rng.uniform(2e-3, 1e-2, (6, 1))
        dr = Rotation.random(6, rng=rng).apply([1.0, 0, 0]) * np.deg2rad(rng.uniform(1.0, 5.0, (6, 1)))
        B[bad] = retract(B[bad], np.column_stack([dt, dr]))
        res = calibrate_hand_eye(M, B, setup="eye_in_hand")
        flags = np.asarray(res.outliers, bool)
        false_flags += int(np.sum(flags & ~bad))
        good += int(np.sum(~bad))
        missed += int(np.sum(~flags & bad))
        tails += int(res.metrics["noise_heavy_tail"])
    assert missed == 0
    # Pope's Gaussian bound alone flags 6 % of the good samples here (21 of 340); with the tail, 2
    assert false_flags <= 6, (false_flags, good)
    assert tails >= 3  # 5 of the 10 sets show a tail
